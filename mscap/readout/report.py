"""The report of a simulated multiplexed read-out (paper appendix C) of a stored design:
the pattern set named on the command line, the ``readout.json`` document, its printed
summary and ``readout.csv``."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from mscap.readout.array import (MAX_DEFAULT_ALL_LEADS, ReadoutError, all_patterns, check_rank, error_bound,
                                 measurement_matrix, noise_gain, simulate_readout)
from mscap.outputs import output_directory, replace_csv, replace_text
from mscap.readout.patterns import optimise_patterns
from mscap.scene.calibration import NoiseModel

__all__ = ["choose_patterns", "readout_report", "text_report", "write_outputs", "CSV_COLUMNS"]


#: Columns of ``readout.csv``: one row per pose and capacitor; errors over the runs (pF).
CSV_COLUMNS = ("pose", "capacitor", "slot_row", "slot_column", "capacitance_pF", "error_mean_pF", "error_std_pF",
               "rms_error_pF", "max_abs_error_pF")


def choose_patterns(array, spec: str, seed: int = 0) -> tuple[np.ndarray, str, float | None]:
    """The patterns named by ``--patterns``, a description and the optimiser's start
    condition number (``None`` when nothing was optimised)."""
    spec = str(spec).strip().lower()
    if spec == "default":           # the rule of patterns.default_patterns
        spec = "all" if array.n_leads <= MAX_DEFAULT_ALL_LEADS else "optimised"
    if spec == "all":
        return all_patterns(array), "all", None
    if spec in ("optimised", "optimized"):
        size = None
    elif re.fullmatch(r"[0-9]+", spec):
        size = int(spec)
    else:
        raise ReadoutError(f"--patterns: expected all, optimised, default or a number of readings, got {spec!r}")
    choice = optimise_patterns(array, size=size, seed=seed)
    return choice.patterns, "optimised", choice.start_condition_number


def _stats(values: np.ndarray) -> dict:
    return {"mean": float(values.mean()), "std": float(values.std())}


def readout_report(design, array, patterns, description: str, noise: NoiseModel, c_on_pF: float,
                   c_off_pF: float, start_condition: float | None = None) -> dict:
    """Simulate the read-out of every pose of ``design`` (a ``StoredDesign``); the
    ``readout.json`` document."""
    m = measurement_matrix(array, patterns)
    condition = check_rank(m)
    errors = simulate_readout(m, design.capacitance_pF, c_on_pF, c_off_pF, noise)
    gain = noise_gain(m)
    names = array.unknown_names
    k = array.k
    poses = []
    for i, pose in enumerate(design.poses):
        error = errors.capacitance_error_pF[:, i]          # (runs, k)
        capacitors = [{"capacitor": j, "slot": list(array.slots[j]),
                       "capacitance_pF": float(design.capacitance_pF[i, j]),
                       "error_mean_pF": float(error[:, j].mean()), "error_std_pF": float(error[:, j].std()),
                       "rms_error_pF": float(np.sqrt(np.mean(error[:, j] ** 2))),
                       "max_abs_error_pF": float(np.abs(error[:, j]).max())} for j in range(k)]
        poses.append({"pose": pose, "max_abs_error_pF": _stats(errors.max_abs_pF[:, i]),
                      "rms_error_pF": _stats(errors.rms_pF[:, i]),
                      "c_on_abs_error_pF": _stats(np.abs(errors.c_on_error_pF[:, i])),
                      "c_off_abs_error_pF": _stats(np.abs(errors.c_off_error_pF[:, i])),
                      "capacitors": capacitors})
    bits = ["".join(map(str, p[:array.rows])) + "|" + "".join(map(str, p[array.rows:])) for p in m.patterns]
    return {
        "design": {"label": design.label, "run": design.run_id, "which": design.which, "k": k,
                   "poses": list(design.poses)},
        "array": {"rows": array.rows, "columns": array.columns, "slots": [list(s) for s in array.slots],
                  "lead_order": "row leads 0..rows-1, then column leads 0..columns-1; 1 = LOGIC (switch ON), "
                                "0 = GND (switch OFF)"},
        "patterns": {"set": description, "count": len(bits), "rank": m.rank, "condition_number": condition,
                     "start_condition_number": start_condition, "bits": bits},
        "unknowns": list(names),
        "switches_pF": {"c_on": c_on_pF, "c_off": c_off_pF},
        "noise": {"relative": noise.relative_shift, "additive_pF": noise.additive_pF, "runs": noise.runs,
                  "seed": noise.seed},
        "predicted": {"noise_gain": dict(zip(names, gain.tolist())),
                      "error_std_pF": dict(zip(names, (gain * noise.additive_std_pF).tolist())),
                      "error_bound_pF": error_bound(m, noise.additive_pF)},
        "poses": poses,
    }


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _grid(array) -> list[str]:
    grid = array.grid()
    lines = ["         " + "".join(f"{'col ' + str(c):>7}" for c in range(array.columns))]
    for r in range(array.rows):
        lines.append(f"  row {r:<3}" + "".join(f"{'.' if i < 0 else i:>7}" for i in grid[r]))
    return lines


def text_report(report: dict, source: str, scene_name: str, array) -> str:
    """The printed summary of a ``readout_report``."""
    d, pat, noise, pred = report["design"], report["patterns"], report["noise"], report["predicted"]
    names = report["unknowns"]
    k = d["k"]
    gain = np.array([pred["noise_gain"][n] for n in names])
    std = np.array([pred["error_std_pF"][n] for n in names])
    lines = [f"{source}: design {d['label']} ({d['which']}), scene {scene_name}: k = {k} capacitors, "
             f"{len(d['poses'])} poses",
             f"array {array.rows} x {array.columns} (slot -> capacitor, '.' empty); "
             f"leads: {_count(array.rows, 'row lead')} then {_count(array.columns, 'column lead')}, "
             "1 = LOGIC = switch ON"]
    lines += _grid(array)
    optimised = ("" if pat["start_condition_number"] is None
                 else f" (greedy start {pat['start_condition_number']:.4g})")
    lines.append(f"patterns: {pat['set']}, {pat['count']} readings of {array.n_leads} leads; {len(names)} unknowns "
                 f"({k} capacitors, C_ON, C_OFF); rank {pat['rank']}, condition number "
                 f"{pat['condition_number']:.4g}{optimised}")
    lines.append(f"switches: C_ON {report['switches_pF']['c_on']:g} pF, C_OFF {report['switches_pF']['c_off']:g} pF; "
                 f"noise: +-{100 * noise['relative']:g} % per capacitor per run, +-{noise['additive_pF']:g} pF "
                 f"per reading; {noise['runs']} runs, seed {noise['seed']}")
    lines.append(f"predicted error std: capacitors {std[:k].min():.3f}-{std[:k].max():.3f} pF (noise gain "
                 f"{gain[:k].min():.3f}-{gain[:k].max():.3f} of the reading noise), C_ON {std[k]:.3f} pF, "
                 f"C_OFF {std[k + 1]:.3f} pF; hard bound +-{pred['error_bound_pF']:.3f} pF")
    width = max(16, *(len(p["pose"]) + 2 for p in report["poses"]))
    lines.append(f"  {'pose':<{width}}{'max |error| (pF)':>18}{'RMS error (pF)':>18}"
                 f"{'|C_ON error| (pF)':>20}{'|C_OFF error| (pF)':>20}   (mean +- std over runs)")
    for p in report["poses"]:
        cells = "".join(f"{s['mean']:>{w - 9}.3f} +- {s['std']:.3f}" for s, w in
                        ((p["max_abs_error_pF"], 18), (p["rms_error_pF"], 18), (p["c_on_abs_error_pF"], 20),
                         (p["c_off_abs_error_pF"], 20)))
        lines.append(f"  {p['pose']:<{width}}{cells}")
    return "\n".join(lines)


def write_outputs(report: dict, directory) -> list[Path]:
    """``readout.csv`` (one row per pose and capacitor, ``CSV_COLUMNS``) and
    ``readout.json`` in ``directory``."""
    directory = output_directory(directory, "readout -o")

    rows = [CSV_COLUMNS] + [[p["pose"], c["capacitor"], *c["slot"]] + [f"{c[key]:.6g}" for key in CSV_COLUMNS[4:]]
                            for p in report["poses"] for c in p["capacitors"]]
    return [replace_csv(directory / "readout.csv", rows),
            replace_text(directory / "readout.json", json.dumps(report, indent=1) + "\n")]
