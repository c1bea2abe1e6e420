"""Did a restructure change a number? C, J and dJ/dq at full precision, before and after.

For each scene: ``build_design`` on the scene's own layout, ``evaluate`` at q = 0, its
``gradient``, then ``evaluate`` warm at ``q = −0.1 g / max|g|`` (one step along −∇J) and
its ``gradient``; every array is saved. Run it on the commit before a change (a git
worktree, with this file copied there if it is newer than the commit) and on the change,
then compare::

    git worktree add /tmp/base <commit>
    (cd /tmp/base && /work/main/.venv/bin/python /work/main/benchmarks/identity.py save base.npz)
    .venv/bin/python benchmarks/identity.py save new.npz
    .venv/bin/python benchmarks/identity.py compare /tmp/base/base.npz new.npz

``save`` imports mscap from the current directory (so from the worktree there). The
comparison prints, per array, whether it is bit-identical and the largest relative
difference; it exits 1 when any array differs by more than ``--rtol`` (default 0: bit
identity).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

SCENES = ("jobs/poking_cross_quick.toml", "jobs/wrist_quick.toml")


def save(out: str, scenes) -> None:
    sys.path.insert(0, os.getcwd())
    from mscap.design.pipeline import build_design
    from mscap.scene import load_scene
    import mscap

    print(f"mscap from {os.path.dirname(mscap.__file__)}", flush=True)
    arrays = {}
    for path in scenes:
        name = os.path.splitext(os.path.basename(path))[0]
        design = build_design(load_scene(path))
        e0 = design.evaluate(design.deformer.zeros())
        g0 = design.gradient(e0)
        e1 = design.evaluate(-0.1 * g0 / np.abs(g0).max(), warm=e0)
        g1 = design.gradient(e1)
        for step, e, g in (("initial", e0, g0), ("step", e1, g1)):
            arrays[f"{name}/{step}/C"] = e.capacitance_pF
            arrays[f"{name}/{step}/J"] = np.array(e.J)
            arrays[f"{name}/{step}/dJdq"] = g
        print(f"{name}: J {e0.J:+.17e} -> {e1.J:+.17e}", flush=True)
    np.savez(out, **arrays)


def compare(a: str, b: str, rtol: float) -> int:
    before, after = np.load(a), np.load(b)
    worst = 0.0
    for key in sorted(set(before) | set(after)):
        if key not in before or key not in after:
            print(f"{key}: only in {'the second' if key in after else 'the first'} file")
            worst = np.inf
            continue
        x, y = before[key], after[key]
        if x.shape != y.shape:
            print(f"{key}: shapes {x.shape} and {y.shape}")
            worst = np.inf
            continue
        scale = max(float(np.abs(x).max(initial=0.0)), 1e-300)
        rel = float(np.abs(x - y).max(initial=0.0)) / scale
        worst = max(worst, rel)
        print(f"{key:<40} {'identical' if np.array_equal(x, y) else 'differs':<10} max rel diff {rel:.3g}")
    print(f"largest relative difference: {worst:.3g}")
    return 0 if worst <= rtol else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("save", help="write the arrays of SCENES to OUT.npz")
    s.add_argument("out")
    s.add_argument("scenes", nargs="*", default=SCENES)
    c = sub.add_parser("compare", help="compare two saved files")
    c.add_argument("a")
    c.add_argument("b")
    c.add_argument("--rtol", type=float, default=0.0)
    args = parser.parse_args()
    if args.command == "save":
        save(args.out, args.scenes)
        return 0
    return compare(args.a, args.b, args.rtol)


if __name__ == "__main__":
    sys.exit(main())
