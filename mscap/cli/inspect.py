"""``mscap inspect results.h5 [--json | --runs | --run ID]``: the per-k table of a
multi-start results file, with the chosen k marked, every run's cost and accuracy, or one
run's history (:mod:`mscap.service.report`)."""

from __future__ import annotations

import json
import math

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("inspect", help="summarise a multi-start results file (HDF5)",
                       description="Print the per-k table of a results file (runs ok/failed, the best "
                                   "run's metric: the read-back bound in mm for a scene designed for "
                                   "read-back (with distance = readback: the bound ⊕ the map's noise), else the min "
                                   "pairwise L1 distance of the poses' capacitance "
                                   "vectors in pF; wall time) with the chosen k marked, the chosen "
                                   "design's estimated error, the same as JSON, or one run's history. "
                                   "The selection is recomputed from the stored runs (see docs/hdf5.md).")
    p.add_argument("results", help="results file (.h5)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--json", action="store_true", help="print JSON for scripts")
    what.add_argument("--runs", action="store_true",
                      help="print every run: metric, its finer-mesh value and error estimate, wall times, "
                           "CPU seconds and peak memory")
    what.add_argument("--run", dest="run_id", metavar="ID", help="print one run's attributes and history")
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.service.report import (cost, cost_text, error_estimates, history_text, margin_resolution,
                                      narrow_necks, narrow_necks_text, reading_choice, reading_plates, reading_text,
                                      resolution_text, runs_table, silent_plates, silent_plates_text, summary_json,
                                      table)
    from mscap.service.checkpoints import kept, kept_text
    from mscap.service.store import finished_ids, read_run, read_store, run_summaries, store_selection

    with read_store(args.results) as store:
        if args.run_id:
            print(history_text(read_run(store, args.run_id)))
            return 0
        if args.runs:
            print(runs_table(read_run(store, rid) for rid in sorted(finished_ids(store))))
            return 0
        selection = store_selection(store)
        errors = error_estimates(store)
        silent, necks, feature, resolution = [], [], 0.0, (math.nan, math.nan, 0.0)
        # How many plates of each design read its poses (a silent plate tells them nothing).
        summaries = run_summaries(store)
        designs = {r.id: read_run(store, r.id) for r in summaries if r.ok and not r.pruned}
        readings = {rid: reading_plates(run.final_capacitance_pF) for rid, run in designs.items()}
        by_reading = reading_choice(summaries, readings, selection.plateau_tol)
        any_silent = any(r.silent for r in readings.values())
        if selection.chosen_run is not None:
            chosen = designs[selection.chosen_run]  # the best of its k: finished, not pruned
            # Calibration may choose the run's initial layout (mscap.service.calibrated).
            initial = selection.chosen_which == "initial"
            silent = silent_plates(chosen.initial_capacitance_pF if initial else chosen.final_capacitance_pF)
            feature, necks = narrow_necks(chosen.initial_outlines if initial else chosen.final_outlines,
                                          str(store.attrs.get("scene_toml", "")))
            if not initial:  # the optimiser's history speaks of its final design
                resolution = margin_resolution(chosen)
        if args.json:
            document = summary_json(selection, errors, readings)
            document["by_reading_plates"] = {"plates": by_reading.plates, "run": by_reading.run,
                                             "best": {str(n): {"score": v, "run": rid}
                                                      for n, (v, rid) in sorted(by_reading.best.items())}}
            document["silent_plates"] = [{"plate": j, "mean_pF": m, "std_pF": sd} for j, m, sd in silent]
            document["narrow_necks"] = [{"plate": j, "width_mm": w, "feature_mm": feature} for j, w in necks]
            document["cost"] = cost(store).as_dict()
            document["kept_starts"] = [{"run": rid, "step": step} for rid, step in kept(args.results)]
            margin, error, noise = resolution
            document["chosen_margin"] = {"min_l1_pF": margin if math.isfinite(margin) else None,
                                         "bias_pF": error if math.isfinite(error) else None, "remesh_noise_pF": noise,
                                         "resolved": bool(error + noise < margin) if math.isfinite(error) else None}
            print(json.dumps(document, indent=1))
        else:
            print(table(selection, f"{args.results}: scene {store.attrs['scene_name']} "
                                   f"(sha256 {store.attrs['scene_sha256'][:12]}…)", errors, readings))
            print(cost_text(cost(store)))
            kept_line = kept_text(args.results)
            if kept_line:
                print(kept_line)
            line = resolution_text(selection.chosen_run, *resolution) if selection.chosen_which == "final" else ""
            if line:
                print(line)
            if silent:
                print(silent_plates_text(selection.chosen_design, silent))
                print(reading_text(selection, readings))
            if any_silent:
                print(by_reading.text(selection.chosen_k))
            if necks:
                print(narrow_necks_text(selection.chosen_design, necks, feature))
    return 0
