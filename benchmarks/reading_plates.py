"""How many plates of each stored design read its poses, and which k the plateau rule
would pick if a design counted as the sensor of the plates that read.

A plate whose capacitance varies over the design poses by less than half the read-out
noise is silent (``mscap.service.report.silent_plates``): fabricated, it reads a constant.
A k-plate design with s silent plates is, as a sensor, a (k − s)-plate one, and its min
pairwise L1 distance over the plates that read is its metric as such. This script groups
every finished, unpruned run of a results file by that count n, takes the best per n (on
the run's mesh and, where checked, on the finer one: the same plates' columns of
``finer_capacitance_pF``) and applies ``choose_k``'s plateau rule to the n — beside the
rule on k as ``mscap run`` applies it. Run::

    .venv/bin/python benchmarks/reading_plates.py out/paper/poking.h5

(Seconds per file; reads a file a running job is writing.)
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mscap.design.history import min_pairwise_l1  # noqa: E402
from mscap.service.report import reading_choice, reading_plates  # noqa: E402
from mscap.service.selection import choose_k  # noqa: E402
from mscap.service.store import finished_ids, read_run, run_summaries, scene_settings, store_selection  # noqa: E402


def main(argv=None) -> None:
    import h5py

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", help="an mscap results file (.h5)")
    args = parser.parse_args(argv)
    with h5py.File(args.results, "r", locking=False) as f:
        tol = scene_settings(f).plateau_tol
        runs = {rid: read_run(f, rid) for rid in sorted(finished_ids(f, failed=False))}
        summaries, selection = run_summaries(f), store_selection(f)
    readings = {rid: reading_plates(r.final_capacitance_pF) for rid, r in runs.items()}

    def finer(rid) -> float:
        """The run's min L1 on the finer mesh over the plates that read (NaN: unchecked)."""
        r, silent = runs[rid], readings[rid].silent
        keep = [j for j in range(r.k) if j not in silent]
        return min_pairwise_l1(r.finer_capacitance_pF[:, keep]) if r.checked else math.nan

    print(f"{'run':<20} {'status':<7} {'min L1':>8} {'reads':>5} {'silent':<8} {'over those':>10} {'finer':>8}")
    count = defaultdict(lambda: defaultdict(int))
    for rid, r in runs.items():
        reading = readings[rid]
        count[r.k][reading.plates] += 1
        print(f"{rid:<20} {r.status:<7} {r.metric:>8.4g} {reading.plates:>2}/{r.k:<2} "
              f"{','.join(map(str, reading.silent)) or '-':<8} {reading.metric_pF:>10.4g} {finer(rid):>8.4g}")
    print("\nplates that read, per k (all designs, pruned ones included):")
    for k in sorted(count):
        print(f"  k = {k}: " + ", ".join(f"{n} plates: {c}" for n, c in sorted(count[k].items())))
    by_reading = reading_choice([s for s in summaries if s.id in runs], readings, tol)
    rules = (("k (mscap run's rule)", selection.chosen_k, lambda rid: runs[rid].finer_metric_pF,
              {s.k: (s.best_metric, s.best_run) for s in selection.per_k if s.best_run is not None}),
             ("plates that read", by_reading.plates, finer, by_reading.best))
    for title, chosen, on_finer, best in rules:
        ks = sorted(best)
        fine = [on_finer(best[k][1]) for k in ks]
        fine_chosen = choose_k(ks, fine, tol) if all(math.isfinite(x) for x in fine) else None
        print(f"\nbest per {title}; plateau_tol {tol:g}:")
        for k, fm in zip(ks, fine):
            print(f"  {'*' if k == chosen else ' '} {k}: {best[k][0]:.4g} pF ({best[k][1]}; finer mesh {fm:.4g})")
        print(f"  chosen: {chosen}; on the finer mesh: {fine_chosen if fine_chosen is not None else '- (unchecked)'}")


if __name__ == "__main__":
    main()
