"""Peak memory of one multi-start worker, per paper scene.

A worker's peak is the larger of its start (the design, the optimiser's evaluations, a
remesh: the new design is built while the old one still exists) and the start's
finer-mesh check (every edge length halved: 3.2× the tets). This runs one start per
scene exactly as a worker does, in one process (``mscap run`` without ``mpirun`` runs the
starts itself), at the scene's largest k (the largest mesh) and reads the peak resident
set from ``/usr/bin/time -v``. Example (about 40 minutes on 2 cores)::

    .venv/bin/python benchmarks/memory.py
    .venv/bin/python benchmarks/memory.py poking_cross glove --max-iterations 3

Writes docs/memory.csv and prints a Markdown table for docs/performance.md.
"""

from __future__ import annotations

import argparse
import csv
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("poking", "poking_cross", "biaxial", "pneumatic", "joystick", "wrist", "glove")


def peak_mb(scene: str, k: int, iterations: int, output: Path) -> tuple[float, float]:
    """Peak RSS (MB) and wall (s) of one start and its finer-mesh check."""
    mscap = str(Path(sys.executable).with_name("mscap"))
    command = ["/usr/bin/time", "-v", mscap, "run", f"jobs/{scene}.toml", "--k-min", str(k), "--k-max", str(k),
               "--seeds", "0:1", "--max-iterations", str(iterations), "-q", "-o", str(output)]
    started = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - started
    found = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        sys.exit(f"{scene}: mscap run failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    return int(found.group(1)) / 1e3, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=SCENES)
    parser.add_argument("--max-iterations", type=int, default=3, help="L-BFGS iterations per level (default 3)")
    parser.add_argument("--csv", default=str(ROOT / "docs" / "memory.csv"))
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from mscap.errors import MscapError
    from mscap.scene import load_scene

    try:
        k_max = {name: load_scene(str(ROOT / "jobs" / f"{name}.toml")).multistart.k_max for name in args.scenes}
    except MscapError as exc:
        sys.exit(f"benchmarks/memory.py: {exc}")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip() or "unknown"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes:
            k = k_max[name]
            mb, wall = peak_mb(name, k, args.max_iterations, Path(tmp) / f"{name}.h5")
            rows.append({"scene": name, "k": k, "max_iterations": args.max_iterations, "peak_MB": round(mb),
                         "wall_s": round(wall, 1), "commit": commit})
            print(f"{name}: k = {k}, peak {mb:.0f} MB, {wall:.0f} s", flush=True)
    with open(args.csv, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print("\n| scene | k | peak per worker (start + finer-mesh check) |\n|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['k']} | {r['peak_MB']} MB |")


if __name__ == "__main__":
    main()
