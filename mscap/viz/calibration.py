"""The figure of ``mscap calibrate`` (paper Fig. 15): reconstruction error per sequence
pose, one line per design."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["error_figure"]


def error_figure(path: Path, scene: Scene, scores) -> None:
    """Mean and max error per sequence pose of ``scores`` (``DesignScore``), mean ± std over
    runs, one line per design; out-of-distribution poses shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cal = scene.calibration
    unit = "mm" if cal.target == "vertices" else "parameter units"
    x = np.arange(len(cal.sequence))
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharex=True)
    for ax, key, title in ((axes[0], "mean_error", "mean per-vertex error"),
                           (axes[1], "max_error", "max per-vertex error")):
        for i in np.flatnonzero(~cal.in_range):
            ax.axvspan(i - 0.5, i + 0.5, color="0.9", lw=0)
        for s in scores:
            m = s.errors.summary()
            line, = ax.plot(x, m[key], lw=1.5, label=f"{s.design.label} (k={s.design.k})")
            low = np.maximum(m[key] - m[key + "_std"], 0.1 * m[key])  # log axis: keep the band > 0
            ax.fill_between(x, low, m[key] + m[key + "_std"], color=line.get_color(), alpha=0.2, lw=0)
        if key == "mean_error" and scores:
            ax.plot(x, scores[0].no_signal, "k:", lw=1, label="no signal (mean training pose)")
        ax.set_title(title if cal.target == "vertices" else title.replace("vertex", "parameter"))
        ax.set_xlabel("sequence pose (grey: outside the training ranges)")
        ax.set_ylabel(f"{unit}, log scale")
        ax.set_yscale("log")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{scene.name}: reconstruction error, mean ± std over {scores[0].errors.mean.shape[0]} "
                 "noisy runs" if scores else scene.name)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
