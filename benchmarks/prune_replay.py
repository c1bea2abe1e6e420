"""Replay pruning rules on an unpruned multi-start's stored histories.

Every start of an unpruned file ran to its end and stored its score (min L1 distance, or
read-back bound) and elapsed time at every accepted step, so any rung rule can be
replayed on it without running anything: starts of each k in index order (one worker),
each asking the master's table (:class:`mscap.service.pruning.Rungs`) at its rungs. A
start stopped at a rung costs its elapsed time to that step. Per rule this prints the
cost (seconds kept / seconds of the whole file; its finer-mesh checks are counted for
the starts that finish) and, per k, how much worse the best surviving start is than the
best start of the file, beside that run's finer-mesh error. Besides the rung rules it
replays the envelope rule (``PruneRule(..., envelope=True)``, :class:`~mscap.service.pruning.Envelope`),
which stops a start only when no gain seen so far could lift it to its k's best.
``--skip-repeats`` leaves out the Lloyd starts that repeat a layout (:func:`mscap.service.selection.repeated_starts`)
from the replayed run, as the service does; the cost stays relative to the whole file.
Example (seconds; the file from ``benchmarks/pruning.py``)::

    .venv/bin/python benchmarks/prune_replay.py out/prune_quick/joystick/full.h5 jobs/joystick_quick.toml --skip-repeats

``--on-top`` replays the envelope rule on a file that was pruned already, its pruned
starts at their stored cost (the paper poking run: docs/performance.md §10)::

    .venv/bin/python benchmarks/prune_replay.py out/paper/poking.h5 jobs/poking.toml --on-top
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RULES = ((2, 3), (2, 4), (3, 3), (3, 4), (5, 3), (5, 4), (10, 3))


def replay(runs, kind: str, rule, leave_out=frozenset(), lean_checks: bool = False) -> tuple[float, dict[int, float]]:
    """Cost fraction and per-k loss of the best metric (> 0: worse) under ``rule``, decided
    by the master's own table (:meth:`mscap.service.pruning.PruneRule.table`): starts in
    index order, largest k first, as one worker of the service runs them (the envelope
    rule shares gains across k, so the order matters to it; the rung table is per k).
    ``lean_checks``: a finishing start that an earlier finished start of its k beats skips
    its finer-mesh check, as the service does since 2026-12-04
    (:func:`mscap.service.multistart.beaten_by`).

    On a file that was pruned already (``--on-top``) its pruned starts cost what they cost
    and stay pruned, and only the starts that ran to their end ask ``rule``'s table: exact
    for the envelope rule, which learns only from finished starts; for the stored rule's
    later rungs an approximation (a start stopped earlier here is missing from them, which
    could have let a later start go on). Losses are then against the file's finished starts."""
    from mscap.service.multistart import Finished, beaten_by
    from mscap.service.pruning import history_values

    table = rule.table(kind)
    cost, survivors = 0.0, {}
    for k in sorted({r.k for r in runs}, reverse=True):
        for r in sorted((r for r in runs if r.k == k and r.id not in leave_out), key=lambda r: r.seed):
            if r.pruned:
                cost += r.wall_s
                continue
            values, final = history_values(rule, kind, r.history)
            stop = next((step for step, value in sorted(values.items()) if not table.decide(k, step, value).keep),
                        None)
            if stop is None:
                beaten = lean_checks and beaten_by(Finished(r.id, k, r.metric, r.bound_mm), survivors.get(k, []))
                cost += r.wall_s + (0.0 if beaten else _check(r))
                survivors.setdefault(k, []).append(r)
                table.finished(k, values, final)
            else:
                cost += float(r.history["time_s"][_row(r.history, stop)])
    finished = [r for r in runs if not r.pruned]
    return cost / _total(runs), {k: _loss(kind, finished, k, mine) for k, mine in survivors.items()}


def replay_synchronous(runs, kind: str, rule, leave_out=frozenset()) -> tuple[float, dict[int, float]]:
    """The same with synchronous successive halving: every start of a k reaches rung 1,
    the best ⌊n/η⌋ (at least one) go on to rung 2, and so on; what a master that parks
    starts at their rungs would do. No start is immune for arriving early."""
    cost, loss = 0.0, {}
    for k in sorted({r.k for r in runs}):
        alive = [r for r in runs if r.k == k and r.id not in leave_out]
        values = {r.id: _rung_scores(rule, kind, r) for r in alive}
        for step in rule.rungs(max(int(r.iterations) for r in alive)):
            ranked = sorted((values[r.id][step], r.seed, r) for r in alive if step in values[r.id])
            if len(ranked) < 2:
                break
            stopped = [r for _, _, r in ranked[max(len(ranked) // rule.eta, 1):]]
            cost += sum(float(r.history["time_s"][_row(r.history, step)]) for r in stopped)
            alive = [r for r in alive if r not in stopped]
        cost += sum(r.wall_s + _check(r) for r in alive)
        loss[k] = _loss(kind, runs, k, alive)
    return cost / _total(runs), loss


def rank_correlation(runs, kind: str, step: int) -> dict[int, float]:
    """Per k, Spearman's rank correlation between the score at accepted step ``step`` and
    the final score (1: the rung ranks the starts as their ends do)."""
    from mscap.service.pruning import score

    out = {}
    for k in sorted({r.k for r in runs}):
        pairs = []
        for r in (r for r in runs if r.k == k):
            h, row = r.history, _row(r.history, step)
            if row is not None:
                final = r.bound_mm if kind == "bound" else -r.metric
                pairs.append((float(score(kind, h["J"], h["d"], h["min_l1_pF"])[row]), final))
        if len(pairs) >= 3:
            a, b = (np.argsort(np.argsort(np.array(col))) for col in zip(*pairs))
            out[k] = float(np.corrcoef(a, b)[0, 1])
    return out


def _rung_scores(rule, kind: str, r) -> dict[int, float]:
    """A run's score (:func:`mscap.service.pruning.score`) at each rung it reached."""
    from mscap.service.pruning import history_values

    return history_values(rule, kind, r.history)[0]


def score_error(kind: str, r) -> float:
    """The relative change of a run's score on the finer mesh: what two runs' scores can
    be told apart by (NaN without a check)."""
    if kind == "bound":
        return abs(r.finer_bound_mm / r.bound_mm - 1.0) if math.isfinite(r.finer_bound_mm) else math.nan
    return r.metric_error


def blind_odds(runs, kind: str, leave_out=frozenset(), fraction: float = 1 / 3,
               error: float | None = None) -> dict[int, tuple[int, int, float]]:
    """Per k: of its ``n`` starts, how many (``w``) end within the score error of the best
    (:func:`score_error` of the best run), and the probability that ``⌊fraction · n⌋``
    starts picked blindly include one of them: ``1 − C(n − w, m) / C(n, m)``. A rule that
    runs a ``fraction`` of the starts to their end and knows nothing of their ends does
    this well; one whose early scores rank the ends (rank correlation near +1) better.
    ``error``: the score error to use for every k (files written before the finer-mesh
    bound was stored have none)."""
    value = (lambda r: r.bound_mm) if kind == "bound" else (lambda r: -r.metric)  # lower is better
    out = {}
    for k in sorted({r.k for r in runs}):
        mine = [r for r in runs if r.k == k and r.id not in leave_out]
        best = min(mine, key=value)
        tol = score_error(kind, best) if error is None else error
        near = [r for r in mine if value(r) <= value(best) + tol * abs(value(best))]
        if not near:  # no finer-mesh score stored
            continue
        n, w = len(mine), len(near)
        m = max(int(fraction * n), 1)
        out[k] = (n, w, 1.0 - math.comb(n - w, m) / math.comb(n, m))
    return out


def _row(history, step: int) -> int | None:
    """The history row of accepted step ``step`` (``None`` if the run never reached it)."""
    rows = np.flatnonzero((np.asarray(history["iteration"]) == step)
                          & (np.asarray(history["event"]).astype(str) == "step"))
    return int(rows[0]) if len(rows) else None


def _check(r) -> float:
    return r.error_estimate_wall_s if math.isfinite(r.error_estimate_wall_s) else 0.0


def _total(runs) -> float:
    return sum(r.wall_s + _check(r) for r in runs)


def _loss(kind: str, runs, k: int, kept) -> float:
    """How much worse the best of ``kept`` is than the best run of k in ``runs`` (> 0: worse)."""
    mine = [r for r in runs if r.k == k]
    if kind == "bound":
        best, survivor = min(r.bound_mm for r in mine), min(r.bound_mm for r in kept)
        return (survivor - best) / best
    best, survivor = max(r.metric for r in mine), max(r.metric for r in kept)
    return (best - survivor) / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", help="an unpruned results file (every start ran to its end); with --on-top, a "
                                     "pruned one")
    parser.add_argument("scene", help="its scene file (for the score and the repeated starts)")
    parser.add_argument("--skip-repeats", action="store_true", help="leave out the repeated Lloyd starts")
    parser.add_argument("--lean-checks", action="store_true",
                        help="finishing starts already beaten within their k skip their finer-mesh check, as the "
                             "service does (the cost stays relative to the whole file, every check included)")
    parser.add_argument("--score-error", type=float,
                        help="the relative finer-mesh error of the score for the odds of a blind third (default: "
                             "each k's best run's own, stored since the finer-mesh bound was)")
    parser.add_argument("--on-top", action="store_true",
                        help="the file was pruned already: replay the envelope rule on the starts that ran to "
                             "their end, the pruned ones costing what they cost (e.g. the paper poking run)")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from mscap.scene import load_scene
    from mscap.scene.loader import with_overrides
    from mscap.service.pruning import PruneRule, score_kind
    from mscap.service.selection import repeated_starts
    from mscap.service.store import finished_ids, read_run, read_store

    store = read_store(args.file)
    runs = [read_run(store, rid) for rid in sorted(finished_ids(store))]
    store.close()
    if args.on_top:
        on_top(args.file, args.scene, runs, args.lean_checks)
        return
    if any(r.pruned for r in runs) or not runs:
        sys.exit(f"{args.file}: needs an unpruned file with finished runs")
    # The file's starts per k (it may have run with --starts-per-k), for the repeated starts.
    scene = with_overrides(load_scene(args.scene), max(Counter(r.k for r in runs).values()))
    kind = score_kind(scene)
    leave_out = frozenset(repeated_starts(scene)) if args.skip_repeats else frozenset()
    if kind == "bound" and not all(math.isfinite(r.bound_mm) for r in runs):
        sys.exit(f"{args.file}: the scene ranks by the read-back bound, but runs lack bound_mm")
    error = max(r.error_estimate for r in runs if math.isfinite(r.error_estimate))
    ks = sorted({r.k for r in runs})
    print(f"{Path(args.file)}: {len(runs)} runs, score {kind}, largest finer-mesh error of C {100 * error:.1f} %"
          + (f", {len(leave_out)} repeated starts left out" if leave_out else ""))
    if kind == "min_l1":  # a difference of capacitances: its error is larger than C's
        best = {k: max((r for r in runs if r.k == k), key=lambda r: r.metric) for k in ks}
        print("the best run's finer-mesh error of C / of the metric, per k: " + ", ".join(
            f"k = {k}: {100 * r.error_estimate:.1f} / {100 * r.metric_error:.1f} %" for k, r in best.items()))
    print("| rule | cost | " + " | ".join(f"loss k = {k}" for k in ks) + " |")
    print("|---|---|" + "---|" * len(ks))
    asynchronous = functools.partial(replay, lean_checks=args.lean_checks)
    for first, eta in ((0, 2),) + RULES:
        for name, how in (("ASHA", asynchronous), ("synchronous", replay_synchronous)):
            if first == 0 and how is replay_synchronous:
                continue
            cost, loss = how(runs, kind, PruneRule(first, eta), leave_out)
            label = "none" if first == 0 else f"{name} {first}:{eta}"
            print(f"| {label} | {cost:.2f} | " + " | ".join(f"{100 * loss.get(k, math.nan):.1f} %" for k in ks)
                  + " |")
    if kind != "J":
        print_envelope_rows(runs, kind, ks, leave_out, args.lean_checks)
    odds = blind_odds(runs, kind, leave_out, error=args.score_error)
    print("\nstarts within their score's finer-mesh error of the best, and the odds that a third of the starts, "
          "picked blindly, hold one:")
    if odds:
        print("  " + ", ".join(f"k = {k}: {w} of {n}, {p:.2f}" for k, (n, w, p) in odds.items())
              + f"; every k: {math.prod(p for _, _, p in odds.values()):.2f}")
    else:
        print("  (no finer-mesh score stored: give --score-error)")
    print("\nrank correlation of the score at a step with the final score, per k:")
    for step in (2, 3, 5, 10, 20):
        rho = rank_correlation(runs, kind, step)
        print(f"  step {step:2d}: " + ", ".join(f"k = {k}: {v:+.2f}" for k, v in rho.items()))


def on_top(file: str, scene_file: str, runs, lean_checks: bool) -> None:
    """``--on-top``: the envelope rule every 3, 5, 10 steps on a pruned file's finished starts."""
    from mscap.scene import load_scene
    from mscap.service.pruning import score_kind

    kind = score_kind(load_scene(scene_file))
    if kind == "J":
        sys.exit(f"{scene_file}: its score (J) has no gains for the envelope rule")
    ks = sorted({r.k for r in runs})
    print(f"{Path(file)}: {len(runs)} runs, {sum(r.pruned for r in runs)} pruned, score {kind}; cost relative "
          f"to the file as it ran")
    print("| rule on top of the stored one | cost | " + " | ".join(f"loss k = {k}" for k in ks) + " |")
    print("|---|---|" + "---|" * len(ks))
    print_envelope_rows(runs, kind, ks, lean_checks=lean_checks)


def print_envelope_rows(runs, kind: str, ks, leave_out=frozenset(), lean_checks: bool = False) -> None:
    """One table row per envelope rule, checking every 3, 5, 10 steps: cost and loss per k."""
    from mscap.service.pruning import PruneRule

    for every in (3, 5, 10):
        cost, loss = replay(runs, kind, PruneRule(every, envelope=True), leave_out, lean_checks)
        print(f"| envelope every {every} steps | {cost:.2f} | "
              + " | ".join(f"{100 * loss.get(k, math.nan):.1f} %" for k in ks) + " |")


if __name__ == "__main__":
    main()
