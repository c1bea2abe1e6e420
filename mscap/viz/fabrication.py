"""``mscap fabricate``'s preview: both conductive layers over each other (bottom rows
blue, top columns red), pads labelled with their lead, every overlap of a row and a
column outside a plate circled."""

from __future__ import annotations

__all__ = ["plot_routing"]


def plot_routing(routing, path, title: str = "") -> None:
    """Draw ``routing`` (:class:`mscap.fabrication.router.Routing`) to the PNG ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from mscap.fabrication.router import CROSSING_MM2

    colours = {"bottom": "tab:blue", "top": "tab:red"}
    minx, miny, maxx, maxy = routing.sheet.bounds
    aspect = (maxy - miny) / max(maxx - minx, 1e-9)
    fig, ax = plt.subplots(figsize=(8, max(3.0, 8 * aspect) + 0.6))
    ax.plot(*np.asarray(routing.sheet.exterior.coords).T, color="0.3", lw=1)
    for net in routing.nets:
        for part in getattr(net.conductor, "geoms", [net.conductor]):
            ax.fill(*np.asarray(part.exterior.coords).T, color=colours[net.layer], alpha=0.35, lw=0)
            ax.plot(*np.asarray(part.exterior.coords).T, color=colours[net.layer], lw=0.6)
        ax.plot(*np.asarray(net.mask.exterior.coords).T, color="0.4", lw=0.5, ls=":")
        ax.text(net.pad.centroid.x, net.pad.centroid.y, net.name, ha="center", va="center", fontsize=6,
                rotation=90 if routing.edge in ("bottom", "top") else 0)
    for c, plate in enumerate(routing.plates):
        i, j = routing.array.slots[c]
        ax.text(plate.centroid.x, plate.centroid.y, f"{c}\nR{i} C{j}", ha="center", va="center", fontsize=7)
    overlaps = routing.overlaps()
    for o in overlaps:
        if o["area_mm2"] < CROSSING_MM2:
            continue
        ax.plot(*o["centroid_mm"], "o", mfc="none", mec="black", ms=9, mew=1.2)
    total = sum(o["area_mm2"] for o in overlaps)
    ax.set_title(f"{title}  {routing.array.rows} x {routing.array.columns} array, connector {routing.edge}, "
                 f"leads {routing.length_mm:.0f} mm, {sum(o['area_mm2'] >= CROSSING_MM2 for o in overlaps)} "
                 f"row/column crossings ({total:.2f} mm² of overlap)",
                 fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
