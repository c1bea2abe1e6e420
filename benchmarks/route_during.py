"""Routing during the optimisation against routing after it (issue 46 item 4,
docs/fabrication.md "Routing during the optimisation").

One start of a scene (``--k``, ``--seed``, ``--init``), optimised twice by ``mscap optimize``:
as the scene is (the plates alone), and with ``[fabrication] route_during_optimisation =
true`` (the routed sensor's capacitances, re-routed at every remesh, refinement and at the
end). Each design is routed (``mscap fabricate``) and calibrated as wired (``mscap calibrate
--wiring``, tared, 100 runs: the scene's noise). One markdown row: the calibrated read-back
error of the plates alone, routed after and routed during; the re-routes of the routed run
(how far the leads' share moved between two routes, the J it changed); wall times.

::

    .venv/bin/python benchmarks/route_during.py jobs/pneumatic_quick.toml --k 3 --seed 2003000 --init lloyd
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from quick_scenes import mscap  # noqa: E402  (the timed mpirun wrapper)


def routed_scene(scene: Path, out: Path) -> Path:
    """The scene with ``route_during_optimisation = true``, in ``out`` (the shipped scenes
    name no other file)."""
    text = scene.read_text()
    if "[fabrication]" in text:
        text = text.replace("[fabrication]", "[fabrication]\nroute_during_optimisation = true", 1)
    else:
        text += "\n[fabrication]\nroute_during_optimisation = true\n"
    path = out / f"{scene.stem}_routed.toml"
    path.write_text(text)
    return path


def errors(calibration: Path) -> dict:
    document = json.loads((calibration / "summary.json").read_text())
    return {d["label"]: d["mean_error"] for d in document["designs"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", type=Path)
    parser.add_argument("--k", type=int)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--init", default="lloyd")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "route_during")
    parser.add_argument("--figure", type=Path, help="both routed designs side by side, as PNG")
    args = parser.parse_args(argv)
    name = f"{args.scene.stem}_k{args.k}_s{args.seed}_{args.init}"
    out = args.out / name
    out.mkdir(parents=True, exist_ok=True)
    log = out / "log.txt"
    routed = routed_scene(args.scene.resolve(), out)
    start = ["--seed", str(args.seed), "--init", args.init, "--no-figure"] + (["--k", str(args.k)] if args.k else [])
    rows = {}
    for kind, scene in (("plates", args.scene), ("during", routed)):
        design = out / f"optimize_{kind}"
        if not (design / "summary.json").exists():
            mscap("optimize", str(scene), *start, "-o", str(design), ranks=1, log=log)
        fab = out / f"fabricate_{kind}"
        if not (fab / "fabrication.json").exists():
            mscap("fabricate", str(design), "--scene", str(args.scene), "-o", str(fab), "-q", ranks=1, log=log)
        calibration = out / f"calibration_{kind}"
        if not (calibration / "summary.json").exists():
            mscap(
                "calibrate", str(args.scene), "--design", str(design), "--baseline", "--wiring", str(fab),
                "-o", str(calibration), "--cache", str(out / f"cache_{kind}.h5"), "-q", ranks=3, log=log)
        rows[kind] = errors(calibration)
    summary = json.loads((out / "optimize_during" / "summary.json").read_text())
    plain = json.loads((out / "optimize_plates" / "summary.json").read_text())

    def pick(kind, suffix):
        return next(v for label, v in rows[kind].items() if label.endswith(suffix))

    plates = pick("plates", "(optimised)")
    after, after_alone = pick("plates", "(as wired)"), pick("plates", "(plates, wired mesh)")
    during, during_alone = pick("during", "(as wired)"), pick("during", "(plates, wired mesh)")
    moves = [r for r in summary["reroutes"] if r["event"] != "start"]
    print("| scene, start | plates alone (optimiser's mesh) | routed after: as wired / plates on its mesh | "
          "routed during: as wired / plates on its mesh | re-routes | largest share move (pF) | "
          "largest J change at a re-route / J | ... / J gained on the route before | optimise (s), plates / routed |")
    print("|---|---|---|---|---|---|---|---|---|")
    largest = max((abs(r["J_after"] - r["J_before"]) / abs(r["J_after"]) for r in moves), default=0.0)
    # the J a re-route changed against the J the optimiser gained on the route before it
    pairs = list(zip(summary["reroutes"], summary["reroutes"][1:]))
    gained = [abs(r["J_after"] - r["J_before"]) / max(abs(r["J_before"] - p["J_after"]), 1e-300) for p, r in pairs]
    print(f"| {args.scene.stem}, {name.split('_', 2)[-1]} | {plates:.3f} | {after:.3f} / {after_alone:.3f} | "
          f"{during:.3f} / {during_alone:.3f} | {len(summary['reroutes'])} | "
          f"{max((r['offset_change_pF'] for r in moves), default=0.0):.3g} | {100 * largest:.3f} % | "
          f"{100 * max(gained, default=0.0):.2f} % | "
          + f"{plain['time_s']:.0f} / {summary['time_s']:.0f} |")
    if args.figure:
        side_by_side(args.figure, [out / "fabricate_plates" / "preview.png", out / "fabricate_during" / "preview.png"],
                     [f"optimised, then routed: {after:.3f} mm as wired",
                      f"routed during the optimisation: {during:.3f} mm as wired"])
    return 0


def side_by_side(path: Path, images: list[Path], titles: list[str]) -> None:
    """The ``mscap fabricate`` previews ``images`` in one row, titled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(images), figsize=(6 * len(images), 5))
    for ax, image, title in zip(axes, images, titles):
        ax.imshow(plt.imread(image))
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
