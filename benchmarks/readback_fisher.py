"""What a design reads and what it cannot: per family grid point, the square roots of the
eigenvalues of its Fisher information with the parameters scaled by their training
ranges, i.e. by how many read-out noise standard deviations a full-range move along each
principal combination of the parameters changes the read-out (0: invisible to it), and
the bound r_g (mm). docs/results.md ("Designing for read-back") quotes the glove's.

    .venv/bin/python benchmarks/readback_fisher.py jobs/glove_quick.toml out/readback/glove_r1.h5 k2_s2000_lloyd
    .venv/bin/python benchmarks/readback_fisher.py jobs/glove_quick.toml out/readback/glove_scene   # mscap optimize DIR

With an ``mscap optimize`` output directory, its initial and final layouts are shown.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def report(label: str, bound, capacitance_pF: np.ndarray) -> None:
    fam = bound.family
    r, (_, _, _, _, _, _, jac, w, _, _) = bound._forward(np.asarray(capacitance_pF, dtype=float))
    span = np.array([a[-1] - a[0] for a in fam.axes])
    print(f"{label}: bound {bound.value(capacitance_pF):.4g} mm")
    for g, values in enumerate(fam.values):
        info = np.einsum("kp,k,kq->pq", jac[g], w[g], jac[g]) * np.outer(span, span)
        z = np.sqrt(np.clip(np.linalg.eigvalsh(info), 0.0, None))
        point = ", ".join(f"{p}={v:g}" for p, v in zip(fam.parameters, values))
        print(f"  [{point}]  noise std per full-range move: {np.array2string(z, precision=2)}  r = {r[g]:.3f} mm")


def main() -> None:
    from mscap.design.readback import ReconstructionBound
    from mscap.scene import load_scene
    from mscap.service.store import read_run, read_store

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("design", help="results file (.h5) or `mscap optimize` directory")
    parser.add_argument("run", nargs="?", help="run id of the results file")
    args = parser.parse_args()
    scene = load_scene(args.scene)
    bound = ReconstructionBound.of(scene)
    if bound is None:
        sys.exit(f"{args.scene}: no design family ([optimizer] design_poses = \"listed\")")
    path = Path(args.design)
    if path.is_dir():
        summary = json.loads((path / "summary.json").read_text())
        for stage, key in (("initial", "initial_capacitance_pF"), ("final", "capacitance_pF")):
            report(f"{path.name} {stage}", bound, [summary[key][p] for p in summary["poses"]])
        return
    with read_store(path) as store:
        record = read_run(store, args.run)
    report(f"{args.run} initial", bound, record.initial_capacitance_pF)
    report(f"{args.run} final", bound, record.final_capacitance_pF)


if __name__ == "__main__":
    main()
