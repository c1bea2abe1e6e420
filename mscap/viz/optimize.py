"""The figure of one ``mscap optimize`` start (paper Fig. 9): the layouts before and
after, and per-pose capacitance bars."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["optimize_figure"]


def optimize_figure(path: Path, scene: Scene, before, after, c_before: np.ndarray, c_after: np.ndarray, poses) -> None:
    """Layouts ``before`` and ``after`` (with the poke centres) and per-pose capacitance bars
    (change from the layout's mean over poses, pF) to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mscap.design.history import min_pairwise_l1
    from mscap.service.report import reading_plates
    from mscap.viz.layouts import draw_layout

    fig, axes = plt.subplots(2, 2, figsize=(10, 8.5))
    colours = plt.get_cmap("tab10")
    for col, (title, layout, caps) in enumerate((("initial", before, c_before), ("optimised", after, c_after))):
        ax = axes[0, col]
        draw_layout(ax, scene.sheet_outline_mm, layout.outlines, colours, fontsize=10,
                    silent=reading_plates(caps).silent)
        for p in scene.poses:
            if p.kind == "poke":
                ax.add_patch(plt.Circle(p.center_mm, p.radius_mm, fill=False, ls="--", color="k", lw=0.8))
                ax.text(*p.center_mm, p.name, fontsize=7, ha="center", va="center")
        ax.set_title(f"{title} layout")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax = axes[1, col]
        n, k = caps.shape
        width = 0.8 / k
        delta = caps - caps.mean(axis=0)
        for j in range(k):
            ax.bar(np.arange(n) + (j - 0.5 * (k - 1)) * width, delta[:, j], width, color=colours(j % 10),
                   label=f"C{j}")
        if n > 10 or max(len(p) for p in poses) > 24:  # family grid poses: numbered, named in summary.json
            ax.set_xticks(np.arange(n), [str(i) for i in range(n)], fontsize=7)
            ax.set_xlabel("design pose (the order of summary.json \"poses\")", fontsize=8)
        else:
            ax.set_xticks(np.arange(n), poses, rotation=20, fontsize=8)
        ax.axhline(0, color="0.5", lw=0.5)
        l1 = min_pairwise_l1(caps)
        ax.set_title(f"{title}: C − mean over poses (min pairwise L1 {l1:.3g} pF)", fontsize=9)
        ax.set_ylabel("ΔC (pF)")
        ax.legend(fontsize=7)
    lo = min(a.get_ylim()[0] for a in axes[1])
    hi = max(a.get_ylim()[1] for a in axes[1])
    for a in axes[1]:
        a.set_ylim(lo, hi)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
