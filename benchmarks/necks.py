"""The narrowest neck of every stored design: can its plates be stencil-cut?

For each run of a results file, each final outline's narrowest neck: the smallest distance
between two of its vertices that are farther apart along the outline (the shorter way
round) than ``NECK_ARC`` × ``--feature`` mm (``mscap.design.objective.NECK_ARC``, the
rule of ``[optimizer] min_feature_mm``). A plate whose outline comes within a few
hundredths of a millimetre of itself has a slit (or a bridge) no Mylar stencil cuts, and
gmsh meshes it with slivers (docs/optimize.md, "Necks"). Also prints the run's remeshes
and the smallest angle of its fresh meshes. Run::

    .venv/bin/python benchmarks/necks.py out/paper/poking.h5 [--feature 1.0] [--runs ID ...]

(Seconds per file.)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mscap.design.objective import NECK_ARC  # noqa: E402
from mscap.geometry.polygons import narrowest_neck  # noqa: E402


def main(argv=None) -> None:
    import h5py

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", help="an mscap results file (.h5)")
    parser.add_argument("--feature", type=float, default=1.0, help="feature size F (mm): pairs more than "
                        "NECK_ARC × F apart along the outline count (default 1)")
    parser.add_argument("--runs", nargs="*", help="only these run ids")
    args = parser.parse_args(argv)
    along, reach = NECK_ARC * args.feature, 3.0 * args.feature
    print(f"{'run':<20} {'status':<8} {'remeshes':>8} {'fresh min °':>11}  narrowest neck per plate (mm; "
          f"pairs > {along:.3g} mm apart along the outline, within {reach:g} mm)")
    with h5py.File(args.results, "r", locking=False) as f:  # a file a running job is writing
        for rid in sorted(f["runs"]):
            if args.runs and rid not in args.runs:
                continue
            run = f["runs"][rid]
            points, offsets = run["final_outline_points_mm"][:], run["final_outline_offsets"][:]
            necks = [narrowest_neck(points[a:b], along, reach) for a, b in zip(offsets[:-1], offsets[1:])]
            events = [e.decode() if isinstance(e, bytes) else e for e in run["history/event"][:]]
            angles = run["history/min_angle_deg"][:]
            fresh = [angles[i] for i, e in enumerate(events) if e == "remesh"]
            cells = " ".join(f"{n:.3f}" if np.isfinite(n) else "-" for n in necks)
            print(f"{rid:<20} {run.attrs['status']:<8} {len(fresh):>8} "
                  f"{(f'{min(fresh):.1f}' if fresh else '-'):>11}  {cells}")


if __name__ == "__main__":
    main()
