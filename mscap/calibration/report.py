"""What ``mscap calibrate`` writes and prints of scored designs: ``errors.csv`` (one row
per design and sequence pose), ``summary.json``, the ``errors.png`` figure and the table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typing import TYPE_CHECKING

from mscap.outputs import output_directory, replace_csv, replace_file, replace_text

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["ERRORS_COLUMNS", "default_paths", "summary", "write_outputs", "text_report"]

#: Error columns of ``errors.csv`` after ``design, k, pose``, the pose parameters and
#: ``in_training_range``: mean ± std over the noisy runs.
ERRORS_COLUMNS = ("mean_error", "mean_error_std", "max_error", "max_error_std")


def default_paths(spec: str) -> tuple[Path, Path]:
    """The simulation cache and the output directory of the design ``spec``: beside a
    results file (``<results>_calibration.h5``, ``<results>_calibration/``) or inside an
    ``mscap optimize`` directory (``DIR/calibration.h5``, ``DIR/calibration/``)."""
    from mscap.outputs import split_design_spec

    results_path = Path(split_design_spec(spec)[0])
    if results_path.is_dir():
        return results_path / "calibration.h5", results_path / "calibration"
    stem = results_path.with_suffix("")
    return Path(f"{stem}_calibration.h5"), Path(f"{stem}_calibration")


def summary(scene: Scene, scores, noise) -> dict:
    """The ``summary.json`` document: settings, then per design its scores averaged over
    the sequence poses."""
    cal = scene.calibration
    document = {"scene": scene.name, "target": cal.target, "reference_pose": cal.reference,
                "kernel": cal.kernel, "smoothing": cal.smoothing, "features": cal.features,
                "min_spread": cal.min_spread if cal.features == "whitened" else None,
                "noise": {"relative_shift": noise.relative_shift, "additive_pF": noise.additive_pF,
                          "runs": noise.runs, "seed": noise.seed},
                "training_poses": len(cal.training), "sequence_poses": len(cal.sequence),
                "out_of_range_poses": int((~cal.in_range).sum()), "designs": []}
    for s in scores:
        m = s.errors.summary()
        document["designs"].append({
            "label": s.design.label, "k": s.design.k, "training_used": s.training_used,
            "training_failed": s.training_failed, "rbf_samples": s.samples,
            "sequence_failed": s.sequence_failed, "simulation_s": s.simulation_s,
            "directions": s.design.k if s.features is None else s.features.directions,
            "spread_noise_std": None if s.features is None else [float(x) for x in s.features.spread],
            "mean_error": float(np.nanmean(m["mean_error"])), "mean_error_std": float(np.nanmean(m["mean_error_std"])),
            "max_error": float(np.nanmean(m["max_error"])), "max_error_std": float(np.nanmean(m["max_error_std"])),
            "no_signal_mean_error": float(np.nanmean(s.no_signal)),
            "mean_error_in_range": float(np.nanmean(m["mean_error"][cal.in_range])),
            "mean_error_out_of_range": (float(np.nanmean(m["mean_error"][~cal.in_range]))
                                        if (~cal.in_range).any() else None)})
    return document


def write_outputs(outdir: Path, scene: Scene, scores, noise, figure=None) -> None:
    """``errors.csv`` (one row per design and sequence pose), ``summary.json`` and, given
    ``figure(path, scene, scores)`` (``mscap calibrate`` gives
    :func:`mscap.viz.calibration.error_figure`), the ``errors.png`` figure (the paper's
    Fig. 15) in ``outdir``."""
    cal = scene.calibration
    outdir = output_directory(outdir, "calibrate -o")

    def rows():
        yield ["design", "k", "pose", *cal.parameters, "in_training_range", *ERRORS_COLUMNS, "no_signal_mean_error"]
        for s in scores:
            m = s.errors.summary()
            for i, row in enumerate(cal.sequence):
                yield [s.design.label, s.design.k, i, *[f"{x:.6g}" for x in row], int(cal.in_range[i]),
                       *[f"{m[c][i]:.6g}" for c in ERRORS_COLUMNS], f"{s.no_signal[i]:.6g}"]

    replace_csv(outdir / "errors.csv", rows())
    replace_text(outdir / "summary.json", json.dumps(summary(scene, scores, noise), indent=2) + "\n")
    if figure is not None:
        replace_file(outdir / "errors.png", lambda path: figure(path, scene, scores))


def text_report(scene: Scene, scores, noise) -> str:
    """The printed table: per design the mean and max error, mean ± std over the runs,
    averaged over the sequence poses, and (whitened features) how many read-out directions
    vary over the family above ``min_spread`` noise standard deviations; then the
    no-signal baseline."""
    cal = scene.calibration
    unit = "mm" if cal.target == "vertices" else "(parameter units)"
    lines = [f"{'design':<34} {'k':>2} {'mean error':>16} {'max error':>16} {'read':>5}  {unit}, mean ± std over "
             f"{noise.runs} runs, averaged over {len(cal.sequence)} sequence poses"]
    for s in scores:
        m = s.errors.summary()
        read = "all" if s.features is None else f"{s.features.directions}/{s.design.k}"
        lines.append(f"{s.design.label:<34} {s.design.k:>2} {np.nanmean(m['mean_error']):>8.3f} ± "
                     f"{np.nanmean(m['mean_error_std']):<6.3f} {np.nanmean(m['max_error']):>8.3f} ± "
                     f"{np.nanmean(m['max_error_std']):<6.3f} {read:>5}")
    lines.append(f"{'no signal (mean training pose)':<34} {'':>2} {np.mean(scores[0].no_signal):>8.3f}")
    if any(s.features is not None for s in scores):
        lines.append(f"read: directions of the read-outs that vary over the training family by at least "
                     f"{cal.min_spread:g} noise standard deviations, of k (docs/calibration.md)")
    return "\n".join(lines)
