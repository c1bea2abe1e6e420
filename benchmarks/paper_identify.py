"""Which setup of the paper's poking experiment reproduces all its numbers at once?

For each discrete reading of what the paper leaves open (the edges held: the two x ends or
all four; the "2cm ball": radius 10 or 20 mm), fit the continuous unknowns — plate size,
cured thickness (a factor on every layer), pitch of the 2 × 2 grid (the pokes stay centred
on the plates) — to the paper's simulated numbers (``benchmarks/data/paper_poking_simulated.csv``:
57 pF at rest, +9 pF on the pressed plate, +1.3 pF on each other) with
:func:`mscap.calibration.identify.solve`, the solver of ``mscap fit``; then compare the fitted
setup's readings with the measured ones (``paper_poking_measured.csv``: the four rest values
and the averages +10.5 / +1.5 pF), and fit the measured ones too, as given and as their
means (``paper_poking_measured_mean.csv``: 58.25 pF at rest; the symmetric model cannot
follow one plate's 53.4 pF). One poke (poke_0) gives
every number by symmetry. Bounds: plate 8–30 mm, thickness 0.4–1.0 of the film
applicator's settings (the shipped file has 0.7), pitch 25–70 mm.

The pitch moves the pokes with the plates, which ``mscap fit``'s names cannot say (one
parameter, two places that move differently), so this script gives the solver its own
forward. Run (about 40 minutes on one core; ``--fits all_r10:simulated`` for one)::

    .venv/bin/python benchmarks/paper_identify.py

Writes ``docs/paper_identify.csv`` and ``docs/paper_identify.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import tomllib
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import write_csv  # noqa: E402
from benchmarks.paper_setups import SCENE, SHIPPED_APPLICATOR, held  # noqa: E402
from mscap.calibration.identify import fit_problem, solve  # noqa: E402
from mscap.calibration.measurements import read_measurements  # noqa: E402
from mscap.errors import MscapError  # noqa: E402
from mscap.fem.simulate import simulate  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.edit import apply, parameter  # noqa: E402
from mscap.scene.loader import select_poses  # noqa: E402

DATA = ROOT / "benchmarks" / "data"
TARGETS = {"simulated": DATA / "paper_poking_simulated.csv", "measured": DATA / "paper_poking_measured.csv",
           "measured_mean": DATA / "paper_poking_measured_mean.csv"}
SETUPS = {"x_r10": ("x", 10.0), "x_r20": ("x", 20.0), "all_r10": ("all", 10.0), "all_r20": ("all", 20.0)}
SPECS = ["capacitors.grid.size_mm=8:30",
         f"thickness_scale={0.4 / SHIPPED_APPLICATOR:.6g}:{1.0 / SHIPPED_APPLICATOR:.6g}",
         "capacitors.grid.pitch_mm=25:70"]
FIELDS = ["setup", "target", "plate_mm", "plate_se", "applicator", "applicator_se", "pitch_mm", "pitch_se",
          "rest_pF", "pressed_pF", "along_x_pF", "along_y_pF", "diagonal_pF", "rms_vs_simulated_pF",
          "rms_vs_measured_pF", "forwards", "seconds", "message"]


def setup_source(holding: str, radius: float) -> str:
    source = held(SCENE.read_text(), holding)
    return apply(str(SCENE), source, [parameter(str(SCENE), tomllib.loads(source), "poses.*.radius_mm")], [radius])


def centred_pokes(text: str, pitch: float) -> str:
    """The four pokes moved onto the plates of a grid of ``pitch`` centred on the sheet."""
    data = tomllib.loads(text)
    params, values = [], []
    for pose in data["poses"]:
        if pose.get("kind") != "poke":
            continue
        for axis in (0, 1):
            params.append(parameter(str(SCENE), data, f"poses.{pose['name']}.center_mm[{axis}]"))
            values.append(50.0 + np.sign(pose["center_mm"][axis] - 50.0) * pitch / 2)
    return apply(str(SCENE), text, params, values)


def readings(problem, values) -> np.ndarray:
    pitch = values[[p.name for p in problem.parameters].index("capacitors.grid.pitch_mm")]
    text = centred_pokes(problem.text_at(values), pitch)
    scene = select_poses(load_scene(SCENE, source=text), list(problem.measurements.poses))
    return simulate(scene).capacitance_pF


def evaluate_with(problem):
    def evaluate(batch):
        out = []
        for values in batch:
            try:
                out.append(readings(problem, values))
            except MscapError as exc:  # a trial point the model refuses: the solver shortens its step
                out.append(str(exc))
        return out
    return evaluate


def summary(table: np.ndarray) -> dict:
    gain = table[1] - table[0]
    return dict(rest_pF=float(table[0].mean()), pressed_pF=float(gain[0]), along_x_pF=float(gain[1]),
                along_y_pF=float(gain[2]), diagonal_pF=float(gain[3]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fits", default="all_r10:simulated,all_r10:measured,all_r20:simulated,all_r20:measured,"
                                          "x_r10:simulated,x_r20:simulated", help="SETUP:TARGET,...")
    parser.add_argument("--max-forwards", type=int, default=12)
    parser.add_argument("--out", default=str(ROOT / "docs" / "paper_identify"))
    args = parser.parse_args(argv)
    rows, details = [], []
    poses = [p.name for p in load_scene(SCENE).poses]  # every setup has the shipped poses
    readings_of = {target: read_measurements(path, poses, 4) for target, path in TARGETS.items()}
    for fit in args.fits.split(","):
        name, _, target = fit.partition(":")
        holding, radius = SETUPS[name]
        source = setup_source(holding, radius)
        problem = fit_problem(str(SCENE), source, SPECS, readings_of[target])
        t0 = time.perf_counter()
        result = solve(problem, evaluate_with(problem), step=0.01, max_iterations=args.max_forwards,
                       say=lambda line: print(f"[{name} {target}] {line}", flush=True))
        full = result.model_pF  # the rows are rest and poke_0, every plate: the table itself
        sims, measured = readings_of["simulated"], readings_of["measured"]
        row = dict(setup=name, target=target,
                   plate_mm=float(result.values[0]), plate_se=float(result.standard_error[0]),
                   applicator=float(result.values[1] * SHIPPED_APPLICATOR),
                   applicator_se=float(result.standard_error[1] * SHIPPED_APPLICATOR),
                   pitch_mm=float(result.values[2]), pitch_se=float(result.standard_error[2]),
                   **summary(full),
                   rms_vs_simulated_pF=float(np.sqrt(np.mean((sims.model(full) - sims.values_pF) ** 2))),
                   rms_vs_measured_pF=float(np.sqrt(np.mean((measured.model(full) - measured.values_pF) ** 2))),
                   forwards=result.forwards, seconds=time.perf_counter() - t0, message=result.message)
        rows.append(row)
        details.append(dict(row, table_pF=full.tolist(),
                            correlation=result.correlation.tolist(), unseparated=result.unseparated))
        print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)
        write_csv(rows, Path(args.out + ".csv"), FIELDS)
        Path(args.out + ".json").write_text(json.dumps(details, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
