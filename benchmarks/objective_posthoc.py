"""Which objective ranks designs as their calibration does? Candidates scored after the fact.

benchmarks/objective_rank.py leaves, per multi-start, a results file whose ``/calibration``
holds every calibrated design's error (the user's read-back: the map fitted on the training
family, scored on the sequence under noise), and a cache with each design's simulated
training family. The design poses the optimiser sees are a sub-grid of that family, so any
objective built on the design poses' capacitances can be evaluated on every design from the
cache, without a simulation, and its Spearman rank correlation with the calibrated error
compared with the bound's (issue 45 item 2: "before and after").

Candidates, each on the design grid (what the optimiser sees), per design:

- ``bound``: the read-back bound the runs optimised (:class:`ReconstructionBound`), from the
  calibration's simulations;
- ``loo``: the leave-one-out error of the calibration's own map (whitened features, its
  kernel and smoothing) fitted on the design grid: each grid pose left out in turn and read
  back, clean, by the map of the others; the RMS over the grid of the mean per-vertex error;
- ``confusion``: for each pair of grid poses, the chance that one pose's noisy reading lies
  nearer the other's (Φ(−√D/2), D the pair's squared distance in noise units, the
  dissimilarity of :class:`ProtocolDissimilarity`) times the pair's RMS per-vertex distance;
  the root mean square over the grid of each pose's expected confusion;
- ``bound_prior/100``, ``bound_prior*10``, ``bound_prior*100``: the bound with its uniform
  prior's precision scaled;
- ``bound_full``: the bound on the whole training grid instead of the design sub-grid;
- ``bound_mean``: the mean of the bound's per-pose values instead of their soft maximum;
- ``noise_grid``: the RMS over the grid of the per-vertex RMS error the read-out noise
  causes through the calibration's map fitted on the grid, linearised (the map's
  Jacobian by central differences times each feature's noise);
- ``bound+loo``, ``bound+confusion``, ``bound+noise_grid``: root sums of squares;
- ``readback``: ``[optimizer] distance = "readback"``'s objective as the optimiser computes it
  (:class:`ReadbackError`: the bound ⊕ :class:`MapNoise`, which is ``noise_grid`` without
  central differences); ``map_noise_full``, ``readback_full``: the same on the whole
  training grid (what a design grid as fine as the training family would give);
- ``loo_training``, ``noise_training``: the same on the whole training family (not available
  to the optimiser, which simulates only the grid: diagnostics of what is predictable at all).

::

    .venv/bin/python benchmarks/objective_posthoc.py out/objective_rank/*.h5

Prints the Spearman correlation of each candidate with the calibrated error per run, over
every design and over the final designs, and the mean over runs (the table of
docs/results.md, "Which objective would track calibration?"; about 6 minutes on one core).
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
import math
import sys
from pathlib import Path

import numpy as np
from scipy.special import ndtr
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mscap.calibration.reconstruction import fit, point_errors  # noqa: E402
from mscap.calibration.service import Candidate, read_cache, targets  # noqa: E402
from mscap.design.readback import (MapNoise, ReadbackError, ReconstructionBound, design_poses,  # noqa: E402
                                   difference_variance, reading_variance)
from mscap.scene import load_scene  # noqa: E402

CANDIDATES = ("bound", "bound_prior/100", "bound_prior*10", "bound_prior*100", "bound_full", "bound_mean", "loo", "confusion", "bound+loo", "bound+confusion", "loo_training",
              "noise_training", "noise_grid", "bound+noise_grid", "readback", "map_noise_full", "readback_full")
#: The candidates that fit a map per left-out pose or on the whole family (most of the time).
SLOW = ("loo", "loo_training", "noise_training", "bound+loo")


def design_rows(scene, designed, training: np.ndarray, reference: np.ndarray | None) -> tuple[np.ndarray, list[int]]:
    """The ``(n_rows, k)`` capacitances of the scene's design poses ``designed`` from the
    cached training family, and the training index of each grid point."""
    fam = designed.family
    values = np.asarray(scene.calibration.training, dtype=float)
    index = [int(np.flatnonzero(np.all(np.isclose(values, v), axis=1))[0]) for v in fam.values]
    c = np.full((len(designed.poses), training.shape[1]), np.nan)
    c[fam.rows] = training[index]
    if fam.reference_row is not None:
        c[fam.reference_row] = reference
    return c, index


def features_of(c: np.ndarray, reference: np.ndarray | None) -> np.ndarray:
    return c if reference is None else c / reference


def calibration_map(cal, f: np.ndarray, y: np.ndarray, reference: np.ndarray | None):
    """The calibration's map fitted on features ``f`` and targets ``y`` as ``mscap calibrate``
    fits it (its kernel, smoothing and, when whitened, each feature's noise at their mean)."""
    noise_std = None
    if cal.features == "whitened":
        noise_std = np.sqrt(reading_variance(f.mean(axis=0), reference, cal.noise)[0])
    return fit(f, y, cal.kernel, cal.smoothing, noise_std, cal.min_spread)


def leave_one_out(scene, c_train: np.ndarray, y: np.ndarray, dim: int, reference: np.ndarray | None) -> float:
    """RMS over the poses of the mean per-vertex error of each pose read back (clean) by the
    calibration's map fitted on the others."""
    cal = scene.calibration
    f = features_of(c_train, reference)
    errors = []
    for i in range(len(f)):
        keep = np.arange(len(f)) != i
        try:
            model = calibration_map(cal, f[keep], y[keep], reference)
            errors.append(point_errors(model.predict(f[i:i + 1]), y[i:i + 1], dim).mean())
        except (ValueError, np.linalg.LinAlgError):
            errors.append(np.nan)
    return float(np.sqrt(np.nanmean(np.square(errors))))


def map_noise(scene, c_train: np.ndarray, y: np.ndarray, dim: int, reference: np.ndarray | None,
              step: float = 1e-4) -> float:
    """RMS over the training poses of the per-vertex RMS error that the read-out noise
    causes through the calibration's own map (fitted on all of them), linearised: the
    map's Jacobian in the features (central differences) times each feature's noise."""
    cal = scene.calibration
    f = features_of(c_train, reference)
    model = calibration_map(cal, f, y, reference)
    var = reading_variance(f, reference, cal.noise)[0]  # (n, k)
    total = np.zeros(len(f))
    for j in range(f.shape[1]):
        h = step * np.maximum(np.abs(f[:, j]), 1e-12)
        up, down = f.copy(), f.copy()
        up[:, j] += h
        down[:, j] -= h
        dy = (model.predict(up) - model.predict(down)) / (2 * h[:, None])  # (n, n_out)
        total += var[:, j] * (dy.reshape(len(f), -1, dim) ** 2).sum(axis=2).mean(axis=1)
    return float(np.sqrt(total.mean()))


def confusion(scene, c_grid: np.ndarray, y: np.ndarray, dim: int, reference: np.ndarray | None) -> float:
    """RMS over the grid poses of Σ_other Φ(−√D/2) · distance (mm)."""
    f = features_of(c_grid, reference)
    a, b = np.triu_indices(len(f), 1)
    delta = f[a] - f[b]
    var = difference_variance(delta, reference, scene.calibration.noise)[0]
    d2 = (delta**2 / var).sum(axis=1)
    points = y.reshape(len(y), -1, dim)
    distance = np.sqrt(((points[a] - points[b]) ** 2).sum(axis=2).mean(axis=1))
    expected = ndtr(-np.sqrt(d2) / 2) * distance
    per_pose = np.zeros(len(f))
    np.add.at(per_pose, a, expected)
    np.add.at(per_pose, b, expected)
    return float(np.sqrt(np.mean(per_pose**2)))


def outlines_of(store, label: str, scene):
    from mscap.service.selection import design_of
    from mscap.service.store import read_run

    run, which = design_of(label)
    if run is None:
        return tuple(scene.layout.outlines)
    record = read_run(store, run)
    return tuple(record.initial_outlines if which == "initial" else record.final_outlines)


def score_run(path: Path, fast: bool = False) -> list[dict]:
    import h5py

    from mscap.service.calibrated import cache_path
    from mscap.service.selection import design_of
    from mscap.service.store import read_store

    original = load_scene(path.with_suffix(".toml"))
    scene, designed = original, design_poses(original)
    cal = scene.calibration
    y_train, dim = targets(original, "training")
    cache = cache_path(path)
    with h5py.File(path, "r") as f:
        labels = [x.decode() if isinstance(x, bytes) else str(x) for x in f["calibration/label"][()]]
        errors = f["calibration/error_mm"][()]
        stored = f["calibration/bound_mm"][()]
    store = read_store(path)
    bound = ReconstructionBound.of(scene, designed)
    values = np.asarray(cal.training, dtype=float)
    counts = [len(np.unique(values[:, i])) for i in range(values.shape[1])]
    full_scene = replace(original, optimizer=replace(original.optimizer, family_grid=counts))
    full = design_poses(full_scene)
    full_bound = ReconstructionBound.of(full_scene, full)
    readback = ReadbackError(bound, MapNoise.of(scene, designed))
    full_noise = MapNoise.of(full_scene, full)
    priors = {name: ReconstructionBound(replace(designed.family, prior=designed.family.prior * f), bound.tau_mm)
              for name, f in (("bound_prior/100", 0.01), ("bound_prior*10", 10.0), ("bound_prior*100", 100.0))}
    rows = []
    try:
        for label, error, stored_bound in zip(labels, errors, stored):
            design = Candidate(label, outlines_of(store, label, original))
            names = ("training",) + ((f"reference_{cal.reference}",) if cal.reference else ())
            data = read_cache(cache, design, names)
            reference = data[f"reference_{cal.reference}"][0] if cal.reference else None
            c_rows, index = design_rows(scene, designed, data["training"], reference)
            c_grid, y_grid = data["training"][index], y_train[index]
            c_full = design_rows(full_scene, full, data["training"], reference)[0]
            value = {"bound": bound.value_and_gradient(c_rows)[0],
                     "readback": readback.value(c_rows), "map_noise_full": full_noise.value(c_full),
                     "bound_mean": float(bound.per_pose_mm(c_rows).mean()),
                     **{name: b.value_and_gradient(c_rows)[0] for name, b in priors.items()},
                     "bound_full": full_bound.value_and_gradient(c_full)[0],
                     "confusion": confusion(scene, c_grid, y_grid, dim, reference)}
            value["readback_full"] = math.hypot(value["bound_full"], value["map_noise_full"])
            if fast:
                value.update({name: math.nan for name in SLOW})
            else:
                value.update(noise_training=map_noise(scene, data["training"], y_train, dim, reference),
                             loo=leave_one_out(scene, c_grid, y_grid, dim, reference),
                             loo_training=leave_one_out(scene, data["training"], y_train, dim, reference))
            value["noise_grid"] = map_noise(scene, c_grid, y_grid, dim, reference)
            value["bound+noise_grid"] = math.hypot(value["bound"], value["noise_grid"])
            value["bound+loo"] = math.hypot(value["bound"], value["loo"])
            value["bound+confusion"] = math.hypot(value["bound"], value["confusion"])
            rows.append(dict(run=path.stem, design=label, final=design_of(label)[1] == "final",
                             error=float(error), stored_bound=float(stored_bound), **value))
    finally:
        store.close()
    return rows


def spearman(x, y) -> float:
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    return float(spearmanr(x[ok], y[ok])[0]) if ok.sum() > 2 else math.nan


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", nargs="+", help="results files of benchmarks/objective_rank.py")
    parser.add_argument("--designs", action="store_true", help="print every design's values too")
    parser.add_argument("--fast", action="store_true", help="leave out " + ", ".join(SLOW) + " (a minute, not six)")
    args = parser.parse_args(argv)
    candidates = [c for c in CANDIDATES if not (args.fast and c in SLOW)]
    logging.disable(logging.WARNING)  # the maps fitted on few poses say so per fit
    paths = [Path(p) for p in args.results if not p.endswith("_calibration.h5")]
    table = {c: ([], []) for c in candidates}
    print("| run | designs | " + " | ".join(candidates) + " |  (Spearman with calibrated error: all / finals)")
    print("|---|---|" + "---|" * len(candidates))
    for path in paths:
        rows = score_run(path, args.fast)
        if args.designs:
            for r in rows:
                print("   ", r["design"], f"error {r['error']:.3f}", f"stored bound {r['stored_bound']:.3f}",
                      " ".join(f"{c} {r[c]:.3f}" for c in candidates))
        err = [r["error"] for r in rows]
        finals = [r for r in rows if r["final"]]
        cells = []
        for c in candidates:
            s_all = spearman([r[c] for r in rows], err)
            s_fin = spearman([r[c] for r in finals], [r["error"] for r in finals])
            table[c][0].append(s_all)
            table[c][1].append(s_fin)
            cells.append(f"{s_all:+.2f} / {s_fin:+.2f}")
        print(f"| {path.stem} | {len(rows)} | " + " | ".join(cells) + " |", flush=True)
    print("| mean | | " + " | ".join(f"{np.nanmean(table[c][0]):+.2f} / {np.nanmean(table[c][1]):+.2f}"
                                     for c in candidates) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
