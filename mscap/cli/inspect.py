"""``mscap inspect results.h5 [--json | --run ID]``: the per-k table of a multi-start
results file, with the chosen k marked, or one run's history."""

from __future__ import annotations

import json
import math

__all__ = ["add_parser", "run", "summary_json", "table"]


def add_parser(sub) -> None:
    p = sub.add_parser("inspect", help="summarise a multi-start results file (HDF5)",
                       description="Print the per-k table of a results file (runs ok/failed, best metric = "
                                   "min pairwise L1 distance of the poses' capacitance vectors, wall time) "
                                   "with the chosen k marked, the same as JSON, or one run's history. "
                                   "The selection is recomputed from the stored runs (see docs/hdf5.md).")
    p.add_argument("results", help="results file (.h5)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--json", action="store_true", help="print JSON for scripts")
    what.add_argument("--run", dest="run_id", metavar="ID", help="print one run's attributes and history")
    p.set_defaults(run=run)


def summary_json(selection) -> dict:
    """The ``--json`` document of a ``Selection``."""
    return {"per_k": [{"k": s.k, "runs_ok": s.runs_ok, "runs_failed": s.runs_failed,
                       "best_metric": s.best_metric, "best_run": s.best_run, "wall_s": s.wall_s}
                      for s in selection.per_k],
            "chosen_k": selection.chosen_k, "chosen_run": selection.chosen_run,
            "plateau_tol": selection.plateau_tol, "plateau_reached": selection.plateau_reached,
            "runs_total": selection.runs_total}


def table(selection, title: str = "") -> str:
    """The per-k table; ``*`` marks the chosen k."""
    lines = [title] if title else []
    lines.append(f"{'':1} {'k':>3} {'ok':>4} {'failed':>6} {'best min L1 (pF)':>17} {'best run':<20} {'time (s)':>9}")
    for s in selection.per_k:
        mark = "*" if s.k == selection.chosen_k else " "
        metric = "-" if s.best_metric is None else f"{s.best_metric:.6g}"
        lines.append(f"{mark} {s.k:>3} {s.runs_ok:>4} {s.runs_failed:>6} {metric:>17} "
                     f"{s.best_run or '-':<20} {s.wall_s:>9.1f}")
    if selection.chosen_k is None:
        lines.append("no successful run: no k chosen")
    else:
        note = "" if selection.plateau_reached else " (largest k with a successful run: plateau not confirmed)"
        lines.append(f"* chosen k = {selection.chosen_k}, run {selection.chosen_run}, plateau_tol "
                     f"{selection.plateau_tol:g}{note}; {selection.runs_total} runs")
    return "\n".join(lines)


def _history(record) -> str:
    from ..store import HISTORY_COLUMNS

    lines = [f"run {record.id}: k = {record.k}, seed {record.seed}, init {record.init}, status {record.status}, "
             f"rank {record.rank}, {record.wall_s:.1f} s, {record.iterations} iterations"
             + (f" ({record.reason})" if record.reason else "")]
    if not record.ok:
        lines.append(f"error: {record.error}")
    if math.isfinite(record.metric):
        lines.append(f"min pairwise L1: {record.metric:.6g} pF")
    names = list(HISTORY_COLUMNS)
    lines.append("\t".join(names))
    columns = [record.history[n] for n in names]
    for row in zip(*columns):
        lines.append("\t".join(v if isinstance(v, str) else f"{v:.6g}" if isinstance(v, float) else str(v)
                               for v in (x.item() if hasattr(x, "item") else x for x in row)))
    return "\n".join(lines)


def run(args) -> int:
    from ..store import read_run, read_store, store_selection

    with read_store(args.results) as store:
        if args.run_id:
            print(_history(read_run(store, args.run_id)))
            return 0
        selection = store_selection(store)
        if args.json:
            print(json.dumps(summary_json(selection), indent=1))
        else:
            print(table(selection, f"{args.results}: scene {store.attrs['scene_name']} "
                                   f"(sha256 {store.attrs['scene_sha256'][:12]}…)"))
    return 0
