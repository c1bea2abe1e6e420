"""Screening line-search trials by their outline terms: the same starts with and without.

``[optimizer] screen_trials`` (default on) rejects a line-search trial before it is
simulated when its outline terms alone (barrier, smoothing) rise by more than
:data:`mscap.design.optimizer.SCREEN_FACTOR` times the first-order gain of the
capacitance term along the step. A screened trial would have been rejected by Armijo
unless d gained more than twice its linear prediction, and the α tried next is the same
either way, so a start's path is unchanged unless a screened trial would have passed (or
would have failed on an inverted mesh, which counts towards a remesh). This script runs
each start twice, screening on and off, in two processes side by side (one core each),
and compares J after every accepted step, the evaluations and the CPU seconds::

    .venv/bin/python benchmarks/screen_trials.py jobs/poking_quick.toml jobs/wrist_quick.toml [--max-iterations 30]

Prints a Markdown table: steps, evaluations off → on, CPU seconds off → on, and whether
the two paths are the same (J equal at every step) or where they part.

``--setting resolve_steps`` compares the other switch of the line search the same way:
``[optimizer] resolve_steps`` (a trial must lower J + δJ, the evaluation's estimated
discretisation error, :mod:`mscap.design.resolution`); the table then also gives why each
start stopped and its final min L1 with its estimated error.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one core per process
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]


def child(scene_path: str, setting: str, on: bool, iterations: int | None, cascade: int | None,
          k: int | None, seed: int) -> dict:
    """One start, in this process: the scene's layout, or a Lloyd start of ``k`` plates."""
    sys.path.insert(0, str(ROOT))
    from mscap.design.optimizer import optimize
    from mscap.design.pipeline import build_design
    from mscap.scene import load_scene
    from mscap.geometry.initial import initial_layout

    scene = load_scene(scene_path)
    scene = replace(scene, optimizer=replace(scene.optimizer, **{setting: on}))
    layout = None if k is None else initial_layout(scene, k, seed, "lloyd")
    cpu = time.process_time()
    sheet = None if layout is None else replace(scene.sheet, layout=layout)
    result = optimize(build_design(scene, sheet=sheet), max_iterations=iterations, cascade_levels=cascade)
    return {"J": [r.J for r in result.history], "events": [r.event for r in result.history],
            "evaluations": int(sum(r.evaluations for r in result.history)), "steps": result.iterations,
            "cpu_s": time.process_time() - cpu, "min_l1_pF": result.evaluation.min_l1_pF,
            "margin_error_pF": result.evaluation.margin_error_pF, "reason": result.reason}


def compare(scene: str, args) -> dict:
    """Both variants of one start side by side."""
    extra = [] if args.max_iterations is None else ["--max-iterations", str(args.max_iterations)]
    extra += [] if args.cascade is None else ["--cascade", str(args.cascade)]
    extra += [] if args.k is None else ["--k", str(args.k), "--seed", str(args.seed)]
    extra += ["--setting", args.setting]
    runs = {screen: subprocess.Popen([sys.executable, __file__, "--child", scene, screen] + extra,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
            for screen in ("on", "off")}
    out = {}
    for screen, run in runs.items():
        stdout, stderr = run.communicate()
        if run.returncode:
            sys.exit(f"{scene} ({args.setting} {screen}): failed\n{stderr[-3000:]}")
        out[screen] = json.loads(stdout.strip().splitlines()[-1])
    return out


def parted(a: list[float], b: list[float]) -> str:
    """``same`` when the two J sequences are equal, else the first record where they differ."""
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return f"part at record {i}"
    return "same" if len(a) == len(b) else f"part at record {min(len(a), len(b))}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", help="scene files")
    parser.add_argument("--max-iterations", type=int, help="accepted steps per level (default: the scene's)")
    parser.add_argument("--cascade", type=int, help="cascade levels (default: the scene's)")
    parser.add_argument("--k", type=int, help="a Lloyd start of K plates instead of the scene's layout")
    parser.add_argument("--seed", type=int, default=0, help="its seed (default 0)")
    parser.add_argument("--setting", default="screen_trials", choices=("screen_trials", "resolve_steps"),
                        help="the [optimizer] switch compared on and off (default screen_trials)")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        scene, on = args.child
        print(json.dumps(child(scene, args.setting, on == "on", args.max_iterations, args.cascade, args.k,
                               args.seed)))
        return
    resolve = args.setting == "resolve_steps"
    middle = ("stopped (off / on) | min L1 off / on (estimated error)" if resolve else
              "evaluations off → on | CPU off → on | min L1 off / on")
    print(f"| scene | steps (off / on) | {middle} | path |")
    print("|---|---|" + "---|" * (middle.count("|") + 1) + "---|")
    for scene in args.scenes:
        r = compare(scene, args)
        off, on = r["off"], r["on"]
        if resolve:
            cells = (f"{off['reason']} / {on['reason']} | {off['min_l1_pF']:.4g} / {on['min_l1_pF']:.4g} pF "
                     f"(±{on['margin_error_pF']:.2g})")
        else:
            cells = (f"{off['evaluations']} → {on['evaluations']} ({on['evaluations'] / off['evaluations']:.2f}) | "
                     f"{off['cpu_s']:.0f} → {on['cpu_s']:.0f} s ({off['cpu_s'] / on['cpu_s']:.2f}×) | "
                     f"{off['min_l1_pF']:.4g} / {on['min_l1_pF']:.4g} pF")
        print(f"| {Path(scene).stem} | {off['steps']} / {on['steps']} | {cells} | {parted(off['J'], on['J'])} |",
              flush=True)


if __name__ == "__main__":
    main()
