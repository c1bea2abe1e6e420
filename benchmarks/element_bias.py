"""How far each elastic element reads a pose's signal from converged, by load and Poisson ratio.

The signal of a pose is its gain C(pose) − C(rest). Three loads, each at ν = 0.30, 0.47
and 0.49 in both silicones:

- **stretch**: a 40 × 40 mm sheet, one 16 mm plate, stretched 1.5× along x between roller
  grips: homogeneous but for the plate, whose carbon layers are twice as stiff as the
  clear silicone around them (a sheet of one material both elements hold exactly: the
  patch tests of tests/fem/test_elastic.py);
- **poke**: the same sheet held at its x edges, a 5 mm ball 4 mm deep on the plate (issue
  44's case);
- **bend**: benchmarks/scenes/glue_bend.toml's 30 mm sheet glued onto a cylinder of
  radius 15 mm (it wraps 2 rad).

Elements: P1 at 5 mm (the default before 2026-12-05), P2 at 5 mm uniform, P2 at 5 mm
refined under the ball and along the held edges (:func:`mscap.scene.sizing.p2_poke_refinement`,
the default of a poked scene since; on the stretch and the bend, which hold no edge and
poke nothing, the same mesh as uniform), and the scene's own default with no ``[elastic]``
table (stretch: P1 at 5 mm; poke: P2 refined with a 10 mm far edge; bend: P2 at 5 mm),
against uniform P2 at 1.25 mm, a quarter of the
edge (on the poke at ν = 0.47 P2 at 1.25 mm is 1.0 % above the limit of P2 at 5, 2.5,
1.25 and 0.8 mm, 1.122 pF). The electrostatic mesh is the same for all (the scene's).
One process, one after the other; the wall is the whole simulation.

Run (about 6 minutes on one core)::

    .venv/bin/python benchmarks/element_bias.py

Writes ``docs/element_bias.csv`` and prints the table of docs/elastic.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head, write_csv  # noqa: E402
from mscap.fem.petsc import petsc  # noqa: E402
from mscap.fem.simulate import simulate  # noqa: E402
from mscap.scene import load_scene  # noqa: E402

#: (label, order, edge, refine_pokes); ``None``: the scene's own default (no ``[elastic]``).
ELEMENTS = [("P1 5 mm", 1, 5.0, False), ("P2 5 mm", 2, 5.0, False), ("P2 5 mm refined", 2, 5.0, True),
            ("default", None, None, None), ("P2 1.25 mm (reference)", 2, 1.25, False)]
NUS = (0.30, 0.47, 0.49)
FIELDS = ["load", "nu", "element", "gain_pF", "reference_pF", "error", "elastic_dofs", "wall_s"]

FLAT = """[capacitors]
min_gap_mm = 1.0
outlines_mm = [[[12.0, 12.0], [28.0, 12.0], [28.0, 28.0], [12.0, 28.0]]]

[[poses]]
name = "rest"
kind = "free"

[[poses]]
name = "pose"
"""
POSES = {
    "stretch": 'kind = "stretch"\nmode = "uniaxial"\nstretch = 1.5\ngrips = "roller"\n',
    "poke": ('kind = "poke"\ncenter_mm = [20.0, 20.0]\nradius_mm = 5.0\ndepth_mm = 4.0\n'
             'held_edges = ["x_min", "x_max"]\n'),
}


def scene_text(load: str, nu: float) -> str:
    if load == "bend":
        text = (ROOT / "benchmarks" / "scenes" / "glue_bend.toml").read_text()
        text = text.split("[[poses]]")[0] + ('[[poses]]\nname = "rest"\nkind = "free"\n\n[[poses]]\nname = "pose"\n'
                                             'kind = "glue"\nobject = "pad"\nradius_mm = 15.0\n')
    else:
        stack = (ROOT / "jobs" / "quick.toml").read_text().split("[capacitors]")[0]
        text = stack.replace("height_mm = 30.0", "height_mm = 40.0") + FLAT + POSES[load]
    return text.replace("poisson_ratio = 0.47", f"poisson_ratio = {nu!r}")


def gain(text: str, order: int | None, edge: float | None, refine: bool | None = False) -> tuple[float, int, float]:
    """The pose's gain (pF), the elastic dofs and the wall; ``order`` ``None``: the scene as loaded."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.toml"
        path.write_text(text)
        scene = load_scene(str(path))
    if order is not None:
        scene = dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, order=order,
                                                                       edge_length_mm=edge, refine_pokes=refine))
    start = time.perf_counter()
    sim = simulate(scene)
    c = sim.capacitance_pF[:, 0]
    return float(c[1] - c[0]), sim.elastic.n_dofs, time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(ROOT / "docs" / "element_bias.csv"))
    parser.add_argument("--loads", nargs="*", default=["stretch", "poke", "bend"])
    args = parser.parse_args(argv)
    petsc()
    rows = []
    for load in args.loads:
        for nu in NUS:
            text = scene_text(load, nu)
            measured = [(label, *gain(text, order, edge, refine)) for label, order, edge, refine in ELEMENTS]
            reference = measured[-1][1]
            for label, g, dofs, wall in measured:
                rows.append(dict(load=load, nu=nu, element=label, gain_pF=g, reference_pF=reference,
                                 error=g / reference - 1, elastic_dofs=dofs, wall_s=wall))
                print(f"{load:<8} nu {nu:.2f} {label:<24} gain {g:9.5f} pF  {100 * (g / reference - 1):+7.2f} %  "
                      f"{dofs:>7d} dofs {wall:6.2f} s", flush=True)
    write_csv(rows, Path(args.out), FIELDS)
    print()
    print("\n".join(table_head("| load | ν | reference gain | P1 5 mm | P2 5 mm | P2 5 mm refined | default | "
                                "wall P1 / P2 / refined / default / reference |")))
    for load in args.loads:
        for nu in NUS:
            sel = [r for r in rows if r["load"] == load and r["nu"] == nu]
            p1, p2, refined, default, ref = sel
            print(f"| {load} | {nu:.2f} | {ref['gain_pF']:.4f} pF | {100 * p1['error']:+.1f} % | "
                  f"{100 * p2['error']:+.1f} % | {100 * refined['error']:+.1f} % | {100 * default['error']:+.1f} % | "
                  f"{p1['wall_s']:.1f} / {p2['wall_s']:.1f} / {refined['wall_s']:.1f} / {default['wall_s']:.1f} / "
                  f"{ref['wall_s']:.1f} s |")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
