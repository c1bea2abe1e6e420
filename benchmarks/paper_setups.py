"""The paper's poking experiment (§4.4, Fig. 8) under every reading of what it leaves unsaid.

The paper states a 10 cm × 10 cm sheet, a 2 × 2 grid, "fix the ends", "a small 2cm ball"
pressed 1.3 cm deep, ε = 2.84 ε0, E = 0.57 / 1.1 MPa, ν = 0.47 and the film applicator's
settings (0.2/0.1/0.2/0.1/0.2 mm per layer, cured layers thinner by an unstated amount).
It leaves open: which edges are held (the two x ends, or all four), whether 2 cm is the
ball's diameter or radius, the plate size and pitch, and the cured thicknesses. Its
simulated numbers: ~57 pF at rest, +9 pF on the pressed capacitor, +1.3 pF on each of the
others; measured: 53.4–60.4 pF, +10.5 and +1.5 pF.

By the layout's symmetry one poke (poke_0 at (30, 30) mm) gives every number: the pressed
plate (C0), its neighbour along x (C1), along y (C2) and across (C3). This script runs
rest + poke_0 of ``jobs/poking.toml`` for every combination of

- holding: ``x`` (x_min, x_max: the shipped scene until 2026-12-06) or ``all`` (four
  edges, the shipped scene since),
- ball radius: 10 mm (a 2 cm diameter) or 20 mm (a 2 cm radius),
- plate size: 12, 18 (shipped), 24 mm squares, 40 mm apart,
- cured thickness as a fraction of the applicator settings: 0.5, 0.7 (shipped), 1.0
  (``applicator`` in the table; the shipped file's thicknesses are 0.7 of the settings),

and writes ``docs/paper_setups.csv``. Run (about 10 minutes on one core)::

    .venv/bin/python benchmarks/paper_setups.py
"""

from __future__ import annotations

import argparse
import itertools
import re
import os
import sys
import time
import tomllib
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import write_csv  # noqa: E402
from mscap.fem.simulate import simulate  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.edit import apply, parameter  # noqa: E402
from mscap.scene.loader import select_poses  # noqa: E402

SCENE = ROOT / "jobs" / "poking.toml"
HOLDINGS = {"x": '["x_min", "x_max"]', "all": '["x_min", "x_max", "y_min", "y_max"]'}
#: The shipped file's thicknesses as a fraction of the applicator settings.
SHIPPED_APPLICATOR = 0.7
FIELDS = ["holding", "radius_mm", "plate_mm", "applicator", "rest_pF", "pressed_pF", "along_x_pF",
          "along_y_pF", "diagonal_pF", "newton", "seconds"]


def held(source: str, holding: str) -> str:
    """``source`` with every pose's ``held_edges`` set to ``holding``'s."""
    return re.sub(r"held_edges = \[[^\]]*\]", f"held_edges = {HOLDINGS[holding]}", source)


def setup_text(holding: str, radius: float, plate: float, applicator: float) -> str:
    """``jobs/poking.toml`` with one reading of the paper's setup."""
    source = SCENE.read_text()
    source = held(source, holding)
    data = tomllib.loads(source)
    names = ["poses.*.radius_mm", "capacitors.grid.size_mm", "thickness_scale"]
    return apply(str(SCENE), source, [parameter(str(SCENE), data, n) for n in names],
                 [radius, plate, applicator / SHIPPED_APPLICATOR])


def run(holding: str, radius: float, plate: float, applicator: float) -> dict:
    scene = select_poses(load_scene(SCENE, source=setup_text(holding, radius, plate, applicator)),
                         ["rest", "poke_0"])
    t0 = time.perf_counter()
    sim = simulate(scene)
    c = sim.capacitance_pF
    gain = c[1] - c[0]
    return dict(holding=holding, radius_mm=radius, plate_mm=plate, applicator=applicator,
                rest_pF=float(c[0].mean()), pressed_pF=float(gain[0]), along_x_pF=float(gain[1]),
                along_y_pF=float(gain[2]), diagonal_pF=float(gain[3]),
                newton=int(sim.poses[1].state.newton_iterations), seconds=time.perf_counter() - t0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "paper_setups.csv"))
    args = parser.parse_args(argv)
    rows = []
    for holding, radius, plate, scale in itertools.product(HOLDINGS, (10.0, 20.0), (12.0, 18.0, 24.0),
                                                           (0.5, 0.7, 1.0)):
        row = run(holding, radius, plate, scale)
        rows.append(row)
        print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)
        write_csv(rows, Path(args.out), FIELDS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
