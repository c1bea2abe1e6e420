"""``mpirun -n N mscap fit SCENE MEASUREMENTS.csv -o FITTED.toml --param NAME[=LO:HI] ...``:
scene parameters identified from measured capacitances."""

from __future__ import annotations

import json

from mscap.cli.common import add_memory_option

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("fit", help="fit scene parameters (thicknesses, permittivity, moduli, a pose's depth, ...) "
                                   "to measured capacitances",
                       description="Least-squares identification of scene parameters from measured "
                                   "capacitances of named poses (scipy's least_squares, trust-region "
                                   "reflective, within bounds; the Jacobian by finite differences, its "
                                   "columns farmed to the MPI workers). Prints the fitted values with "
                                   "standard errors and correlations, names the parameters the readings "
                                   "cannot separate, the residual of every reading, and writes the scene "
                                   "with the fitted values (a normal scene: run, calibrate and fabricate "
                                   "take it as it is).")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("measurements", help="CSV of readings, one per row: a 'pose' column, optionally 'run' (the "
                                        "session a reading was taken in), and C0, C1, ... (pF)")
    p.add_argument("-o", "--output", required=True, metavar="FITTED.toml", help="the fitted scene to write")
    p.add_argument("--param", action="append", required=True, metavar="NAME[=LO:HI]",
                   help="a parameter to fit, by its place in the scene file: materials.clear.relative_permittivity, "
                        "layers.dielectric.thickness_mm, thickness_scale (every layer's thickness times one factor), "
                        "materials.carbon.youngs_modulus_MPa, poses.poke_0.depth_mm, poses.*.depth_mm (every pose's, "
                        "together), capacitors.grid.size_mm, capacitors.grid.center_mm[0]; bounds LO:HI (default: "
                        "a positive value within a factor 10 of the scene's); repeat for more")
    p.add_argument("--step", type=float, default=0.01, metavar="H",
                   help="finite-difference step, relative to each parameter's value (default: %(default)s)")
    p.add_argument("--max-forwards", type=int, default=30, metavar="N",
                   help="at most N trial points of the least-squares iteration, each one forward and one more "
                        "per parameter where a Jacobian is taken (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print the fit as one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    import datetime
    import os
    from pathlib import Path

    from mscap import farm
    from mscap.calibration.identify import fit_problem, fitted_text, forward, solve
    from mscap.calibration.identify_report import fit_record, report_text
    from mscap.calibration.measurements import read_measurements
    from mscap.cli.common import load_scene_for, progress_printer, rank_logging, start_mpi
    from mscap.errors import CalibrationError, MscapError
    from mscap.outputs import replace_text

    comm = start_mpi().COMM_WORLD
    rank_logging(comm)
    scene = load_scene_for(args)
    if not 0 < args.step < 0.5:
        raise CalibrationError(f"--step must lie in (0, 0.5), got {args.step}")
    if args.max_forwards < 1:
        raise CalibrationError(f"--max-forwards must be >= 1, got {args.max_forwards}")
    output = Path(args.output)
    if output.resolve() == Path(args.scene).resolve():
        raise CalibrationError(f"-o {args.output}: that is the scene fitted; write the fitted scene elsewhere")
    folder = output.parent if str(output.parent) else Path(".")
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise CalibrationError(f"-o {args.output}: {folder} is not a writable directory (checked before the fit, "
                               f"not after it)")
    measurements = read_measurements(args.measurements, [p.name for p in scene.poses], len(scene.layout.outlines))
    problem = fit_problem(scene.path, scene.source, args.param, measurements)
    say = progress_printer(args.quiet or comm.Get_rank() > 0)

    def make_work(ask):
        def work(task):
            label, values = task
            try:
                return label, forward(problem, values)
            except MscapError as exc:  # a trial point the model refuses: the fit shortens its step
                return label, str(exc)
        return work

    def master(execute, stop):
        def evaluate(batch):
            tables = {}
            execute(list(enumerate(batch)), lambda result: tables.__setitem__(*result))
            if stop.requested:
                raise MscapError(f"stopped ({stop.reason}) during the fit: nothing written")
            return [tables[i] for i in range(len(batch))]

        result = solve(problem, evaluate, ranks=comm.Get_size(), step=args.step,
                       max_iterations=args.max_forwards, say=say)
        when = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
        replace_text(args.output, fitted_text(problem, result, when))
        return result

    result = farm.run(comm, make_work, master, "stopped: nothing written", say or (lambda line: None),
                      batches=True)
    if comm.Get_rank() != 0 or result is None:
        return 0
    if args.json:
        print(json.dumps(fit_record(problem, result)))
    else:
        print(report_text(problem, result))
        print(f"wrote {args.output}")
    return 0
