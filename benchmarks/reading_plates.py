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
from mscap.service.report import reading_plates  # noqa: E402
from mscap.service.selection import choose_k  # noqa: E402
from mscap.service.store import finished_ids, read_run, scene_settings  # noqa: E402


def main(argv=None) -> None:
    import h5py

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", help="an mscap results file (.h5)")
    args = parser.parse_args(argv)
    with h5py.File(args.results, "r", locking=False) as f:
        tol = scene_settings(f).plateau_tol
        runs = [read_run(f, rid) for rid in sorted(finished_ids(f, failed=False))]
    print(f"{'run':<20} {'status':<7} {'min L1':>8} {'reads':>5} {'silent':<8} {'over those':>10} {'finer':>8}")
    by_k, by_n, count = {}, {}, defaultdict(lambda: defaultdict(int))
    for r in runs:
        reading = reading_plates(r.final_capacitance_pF)
        keep = [j for j in range(r.k) if j not in reading.silent]
        finer = min_pairwise_l1(r.finer_capacitance_pF[:, keep]) if r.checked else math.nan
        count[r.k][reading.plates] += 1
        print(f"{r.id:<20} {r.status:<7} {r.metric:>8.4g} {reading.plates:>2}/{r.k:<2} "
              f"{','.join(map(str, reading.silent)) or '-':<8} {reading.metric_pF:>10.4g} {finer:>8.4g}")
        if r.pruned:
            continue
        if r.metric > by_k.get(r.k, (-math.inf,))[0]:
            by_k[r.k] = (r.metric, r.id, r.finer_metric_pF)
        if reading.metric_pF > by_n.get(reading.plates, (-math.inf,))[0]:
            by_n[reading.plates] = (reading.metric_pF, r.id, finer)
    print("\nplates that read, per k (all designs, pruned ones included):")
    for k in sorted(count):
        print(f"  k = {k}: " + ", ".join(f"{n} plates: {c}" for n, c in sorted(count[k].items())))
    for title, best in (("k (mscap run's rule)", by_k), ("plates that read", by_n)):
        ks = sorted(best)
        chosen = choose_k(ks, [best[k][0] for k in ks], tol)
        finer = [best[k][2] for k in ks]
        finer_chosen = choose_k(ks, finer, tol) if all(math.isfinite(x) for x in finer) else None
        print(f"\nbest per {title}; plateau_tol {tol:g}:")
        for k in ks:
            m, rid, fm = best[k]
            print(f"  {'*' if k == chosen else ' '} {k}: {m:.4g} pF ({rid}; finer mesh {fm:.4g})")
        print(f"  chosen: {chosen}; on the finer mesh: {finer_chosen if finer_chosen is not None else '- (unchecked)'}")


if __name__ == "__main__":
    main()
