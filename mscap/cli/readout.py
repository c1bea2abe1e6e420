"""``mscap readout SCENE --design results.h5[:RUN]``: simulate the multiplexed read-out
(paper appendix C) of a stored design: its array wiring, the lead-pattern set and how
well least squares recovers each pose's capacitances from noisy readings."""

from __future__ import annotations

import json

from mscap.cli.common import add_noise_options
from mscap.readout.array import C_OFF_PF, C_ON_PF

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("readout", help="simulate the multiplexed read-out of a design's capacitor array",
                       description="Wire a stored design's capacitors as an m x n array (row leads to the "
                                   "bottom plates, column leads to the top plates), choose lead patterns, "
                                   "and simulate noisy readings of every pose: per run each capacitor "
                                   "shifts by a uniform +-relative factor, each reading gets a uniform "
                                   "+-additive error; least squares recovers the capacitances and the "
                                   "switches' C_ON and C_OFF. Prints the wiring, the pattern set's rank "
                                   "and condition number and per pose the recovery error (see "
                                   "docs/readout.md).")
    p.add_argument("scene", help="scene file of the results (its name must match the file's)")
    p.add_argument("--design", required=True, metavar="FILE.h5[:RUN]",
                   help="results file, optionally with a run id (default: the selection's chosen run)")
    p.add_argument("--which", choices=("final", "initial"), default="final", help="which layout of the run")
    p.add_argument("--rows", type=int, metavar="M", help="array rows (default: ceil(sqrt(k)))")
    p.add_argument("--columns", type=int, metavar="N", help="array columns (default: ceil(k / rows))")
    p.add_argument("--wiring", metavar="FABRICATION_JSON",
                   help="the array as `mscap fabricate` routed it (its fabrication.json): which capacitor sits "
                        "in which row and column, instead of --rows/--columns and capacitor order")
    p.add_argument("--patterns", default="default", metavar="all|optimised|default|N",
                   help="every pattern ('all'), the optimised set of 2 x unknowns ('optimised'), "
                        "all patterns up to 10 leads and the optimised set beyond ('default'), or an "
                        "optimised set of N readings")
    p.add_argument("--c-on", type=float, default=C_ON_PF, metavar="PF", help="switch ON capacitance (pF)")
    p.add_argument("--c-off", type=float, default=C_OFF_PF, metavar="PF", help="switch OFF capacitance (pF)")
    p.add_argument("--runs", type=int, default=100, help="simulated read-outs per pose")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise (and of random candidate patterns)")
    add_noise_options(p, relative_shift=0.15, additive_pF=2.0)
    p.add_argument("-o", "--output", metavar="DIR", help="write DIR/readout.csv and DIR/readout.json")
    p.add_argument("--json", action="store_true", help="print the JSON document instead of the table")
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.outputs import output_directory
    from mscap.errors import ReadoutError
    from mscap.readout.array import check_switches, grid_array, read_wiring
    from mscap.readout.report import choose_patterns, readout_report, text_report, write_outputs
    from mscap.scene.calibration import NoiseModel
    from mscap.scene import load_scene
    from mscap.service.designs import load_design, split_design_spec

    # Every argument before any work: a bad one costs nothing.
    check_switches(args.c_on, args.c_off)
    if args.wiring and (args.rows or args.columns):
        raise ReadoutError("--wiring gives the array; leave out --rows and --columns")
    noise = NoiseModel(args.relative_shift, args.additive_pF, args.runs, args.seed)
    if args.output:
        output_directory(args.output, "readout -o")
    path = split_design_spec(args.design)[0]
    scene = load_scene(args.scene)
    design = load_design(scene, args.design, args.which)
    k = design.capacitance_pF.shape[1]
    array = read_wiring(args.wiring, k) if args.wiring else grid_array(k, args.rows, args.columns)
    patterns, description, start = choose_patterns(array, args.patterns, args.seed)
    report = readout_report(design, array, patterns, description, noise, args.c_on, args.c_off, start)
    report["scene"] = scene.name
    report["design"]["file"] = str(path)
    files = write_outputs(report, args.output) if args.output else []
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    print(text_report(report, str(path), scene.name, array))
    for f in files:
        print(f"wrote {f}")
    return 0
