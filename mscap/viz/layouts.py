"""The figure of a multi-start results file (``mscap plot``): the best optimised layout
per k, the chosen k highlighted, and the best metric against k (paper Fig. 10); and
:func:`draw_layout`, the layout drawing every figure shares."""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mscap.service.selection import design_of

__all__ = ["Panel", "panels", "grid_shape", "plot_results", "draw_layout", "PANEL_SIZE_IN", "CHOSEN_COLOUR",
           "MAX_COLUMNS"]

log = logging.getLogger(__name__)

#: Size of one grid panel (width, height) in inches; the figure is ``ncols × nrows`` of them.
PANEL_SIZE_IN = (3.2, 3.0)
#: Frame and title colour of the chosen k.
CHOSEN_COLOUR = "crimson"
#: At most this many panels per row.
MAX_COLUMNS = 4


@dataclass(frozen=True)
class Panel:
    """One k of the grid: its best run (``None`` if no run of k succeeded), that run's
    metric (pF), run counts, and whether k is the chosen one."""

    k: int
    run_id: str | None
    metric: float | None
    runs_ok: int
    runs_failed: int
    chosen: bool
    bound_mm: float | None = None  # the read-back bound, when the selection uses it
    silent: tuple[int, ...] = ()  # plates of the run's design that read nothing (report.silent_plates)
    #: The calibrated error of the k's best calibrated design and its label (``RUN`` or
    #: ``RUN:initial``), when the selection was made on calibrated error.
    error_mm: float | None = None
    design: str | None = None

    @property
    def initial(self) -> bool:
        """Is the panel's layout its run's initial one (calibration preferred it)?"""
        return design_of(self.design or "")[1] == "initial"

    @property
    def empty(self) -> bool:
        return self.run_id is None

    @property
    def title(self) -> str:
        if self.empty:
            return f"k = {self.k}, no successful run"
        score = f"bound {self.bound_mm:.3g} mm" if self.bound_mm is not None else f"min L1 = {self.metric:.4g} pF"
        if self.error_mm is not None:
            score = f"calibrated {self.error_mm:.3g} mm" + (" (initial layout)" if self.initial else "")
        reads = f"\n{self.k - len(self.silent)} of {self.k} plates read the poses" if self.silent else ""
        return f"k = {self.k}, {score}{reads}" + (" (chosen)" if self.chosen else "")

    @property
    def note(self) -> str:
        """Text of an empty panel."""
        if not self.empty:
            return ""
        if self.runs_failed:
            return "its only run failed" if self.runs_failed == 1 else f"all {self.runs_failed} runs failed"
        return "no runs"


def panels(selection) -> list[Panel]:
    """One ``Panel`` per k of a ``mscap.service.selection.Selection`` (ascending k); exactly the
    chosen k (if any) is flagged. Chosen on calibrated error, a panel shows the k's best
    calibrated design."""
    def run_of(s):
        return design_of(s.best_design)[0] if s.best_design else s.best_run
    return [Panel(k=s.k, run_id=run_of(s), metric=s.best_metric, runs_ok=s.runs_ok,
                  runs_failed=s.runs_failed, chosen=s.k == selection.chosen_k and run_of(s) is not None,
                  bound_mm=s.best_bound_mm, error_mm=s.best_error_mm, design=s.best_design)
            for s in selection.per_k]


def grid_shape(n_k: int) -> tuple[int, int]:
    """(rows, columns) of the grid for ``n_k`` layout panels plus the metric panel."""
    n = n_k + 1
    cols = min(MAX_COLUMNS, n)
    return math.ceil(n / cols), cols


def _sheet_outline(store) -> np.ndarray | None:
    """The stored scene's sheet outline (mm), or ``None`` if it cannot be read."""
    from mscap.scene._toml import Table
    from mscap.errors import MscapError
    from mscap.scene.loader import _read_sheet

    try:
        data = tomllib.loads(store.attrs["scene_toml"])
        return _read_sheet(Table(str(store.attrs.get("scene_path", "?")), "sheet", data.get("sheet", {})))
    except (MscapError, tomllib.TOMLDecodeError, KeyError) as exc:
        log.warning("%s: no sheet outline drawn (%s)", store.filename, exc)
        return None


def draw_layout(ax, sheet: np.ndarray | None, outlines, colours, fontsize: float = 8, silent=()) -> None:
    """Sheet outline in grey, plates filled in ``colours(j)`` and numbered (also
    ``mscap optimize``'s layout figure); the ``silent`` plates (they read nothing,
    :func:`mscap.service.report.silent_plates`) grey and hatched, numbered "j silent"."""
    if sheet is not None:
        ax.plot(*np.vstack([sheet, sheet[:1]]).T, color="0.3", lw=1)
    for j, o in enumerate(outlines):
        closed = np.vstack([o, o[:1]])
        colour = "0.55" if j in silent else colours(j % 10)
        ax.fill(*closed.T, color=colour, alpha=0.35, hatch="////" if j in silent else None)
        ax.plot(*closed.T, color=colour, lw=1)
        ax.text(*o.mean(axis=0), f"{j} silent" if j in silent else str(j), ha="center", va="center",
                fontsize=fontsize)
    ax.set_aspect("equal")


def _frame(ax, colour, width) -> None:
    for spine in ax.spines.values():
        spine.set_edgecolor(colour)
        spine.set_linewidth(width)


def _metric_panel(ax, selection, items: list[Panel]) -> None:
    ok = [p for p in items if not p.empty]
    calibrated = selection.by_calibration
    bound = selection.by_bound or calibrated  # lower is better: the band reaches down to b/(1 + tol)
    value = (lambda p: p.error_mm) if calibrated else (lambda p: p.bound_mm) if bound else (lambda p: p.metric)
    ok = [p for p in ok if value(p) is not None]
    if ok:
        ax.plot([p.k for p in ok], [value(p) for p in ok], "o-", color="0.2", ms=4, lw=1)
    chosen = next((p for p in items if p.chosen), None)
    if chosen is not None:
        m, tol = value(chosen), selection.plateau_tol
        letter = "e" if calibrated else "b"
        low, high, label = ((m / (1 + tol), m, f"{letter}(k={chosen.k})/(1 + {tol:g}) … {letter}") if bound
                            else (m, (1 + tol) * m, f"m(k={chosen.k}) … (1 + {tol:g})·m"))
        ax.axhspan(low, high, color=CHOSEN_COLOUR, alpha=0.15, lw=0, label=label)
        ax.axhline(m, color=CHOSEN_COLOUR, lw=0.8, ls="--")
        ax.plot([chosen.k], [m], "o", color=CHOSEN_COLOUR, ms=8, mfc="none", mew=2)
        ax.legend(fontsize=7, loc="best")
    for p in items:
        if p.empty:
            ax.text(p.k, 0.04, "×\nfailed" if p.runs_failed else "×\nno runs", transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", color="0.4", fontsize=7)
    ax.set_xticks([p.k for p in items])
    if items:
        ax.set_xlim(items[0].k - 0.5, items[-1].k + 0.5)
    ax.set_xlabel("k")
    ax.set_ylabel("best calibrated error (mm)" if calibrated else "best read-back bound (mm)" if bound
                  else "best min L1 (pF)")
    ax.set_title(("best calibrated error per k" if calibrated else "best bound per k" if bound else "best metric per k")
                 + ("" if chosen is not None else " (no k chosen)"), fontsize=9)
    ax.grid(alpha=0.3)


#: The figure formats ``mscap plot -o`` writes, by the output's suffix (matplotlib's Agg
#: canvas); a name without a suffix is a PNG.
FIGURE_FORMATS = ("png", "pdf", "svg", "eps", "ps", "jpg", "jpeg", "tif", "tiff", "webp")


def figure_format(output) -> str:
    """The format of a figure file named ``output``: its suffix's, or ``png`` without one
    (matplotlib would add ``.png`` to the name, and the figure would not be where asked);
    a ``ValueError`` for a suffix no figure has."""
    suffix = Path(output).suffix.lower().lstrip(".")
    if suffix and suffix not in FIGURE_FORMATS:
        raise ValueError(f"{output}: a figure is one of .{', .'.join(FIGURE_FORMATS)} (or a name without a suffix: "
                         f"PNG), not .{suffix}")
    return suffix or "png"


def plot_results(results, output, dpi: int = 120, fmt: str = "png") -> list[Panel]:
    """Draw the figure of the results file ``results`` to ``output`` in the format ``fmt``
    (:func:`figure_format`); returns the panels.

    Raises
    ------
    StoreError
        The file is not an mscap results file, or holds no finished run.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dataclasses import replace

    from mscap.service.report import reading_plates
    from mscap.service.store import StoreError, finished_ids, read_run, read_store, store_selection

    with read_store(results) as store:
        if not finished_ids(store):
            raise StoreError(f"{results}: no finished runs stored yet; nothing to plot")
        selection = store_selection(store)
        runs = {p.k: read_run(store, p.run_id) for p in panels(selection) if not p.empty}
        items = panels(selection)
        items = [replace(p, silent=reading_plates(runs[p.k].initial_capacitance_pF if p.initial else
                                                  runs[p.k].final_capacitance_pF).silent) if p.k in runs else p
                 for p in items]
        sheet = _sheet_outline(store)
        initial = {p.k for p in items if p.initial}
        outlines = {k: run.initial_outlines if k in initial else run.final_outlines for k, run in runs.items()}
        scene_name = str(store.attrs.get("scene_name", "?"))

    rows, cols = grid_shape(len(items))
    fig, axes = plt.subplots(rows, cols, figsize=(cols * PANEL_SIZE_IN[0], rows * PANEL_SIZE_IN[1]),
                             squeeze=False)
    flat = axes.ravel()
    colours = plt.get_cmap("tab10")
    limits = None
    if sheet is not None:
        lo, hi = sheet.min(axis=0), sheet.max(axis=0)
        pad = 0.04 * float((hi - lo).max())
        limits = (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)
    for ax, p in zip(flat, items):
        if p.empty:
            if sheet is not None:
                ax.plot(*np.vstack([sheet, sheet[:1]]).T, color="0.8", lw=1, ls=":")
                ax.set_aspect("equal")
            ax.text(0.5, 0.5, p.note, transform=ax.transAxes, ha="center", va="center", color="0.4")
            ax.set_xticks([])
            ax.set_yticks([])
            _frame(ax, "0.7", 0.8)
        else:
            draw_layout(ax, sheet, outlines[p.k], colours, silent=p.silent)
            ax.tick_params(labelsize=7)
            if p.chosen:
                _frame(ax, CHOSEN_COLOUR, 4)
        if limits is not None:
            ax.set_xlim(*limits[0])
            ax.set_ylim(*limits[1])
        ax.set_title(p.title, fontsize=9, color=CHOSEN_COLOUR if p.chosen else "black",
                     fontweight="bold" if p.chosen else "normal")
    _metric_panel(flat[len(items)], selection, items)
    for ax in flat[len(items) + 1:]:
        ax.axis("off")
    if selection.chosen_k is None:
        headline = "no successful run: no k chosen"
    else:
        headline = (f"chosen k = {selection.chosen_k} (plateau_tol {selection.plateau_tol:g}"
                    + ("" if selection.plateau_reached else ", plateau not confirmed") + ")")
    what = "best calibrated design" if selection.by_calibration else "best layout"
    fig.suptitle(f"{scene_name}: {what} per k; {headline}", fontsize=10)
    fig.tight_layout()
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=dpi, format=fmt)
    plt.close(fig)
    return items
