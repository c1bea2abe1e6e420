"""Virtual calibration of designs: simulate the scene's pose family once per design
(farmed over MPI, cached in HDF5), fit the reconstruction, score it under noise.

:func:`simulate_family` fills the cache: for every design, the capacitances of the
training grid and of the evaluation sequence (:mod:`mscap.scene.calibration`), simulated in
chunks of poses that share one mesh; the master writes each chunk as it arrives and
flushes, so a killed job keeps what finished and a rerun does only the rest. The cache
is valid while the scene's physics and the family are unchanged (noise, kernel and
smoothing are not part of that: re-scoring with other noise settings costs no
simulation). :func:`evaluate` then fits :mod:`mscap.calibration.reconstruction` on each design's
training capacitances and scores the sequence under the noise model.

Cache layout (``format = "mscap-calibration"``)::

    /                      attrs: format, schema_version, physics_sha256, family_sha256
    /designs/<key>         (key: layout_<outline hash>) attrs: label (the first), k;
                           outline_points_mm, outline_offsets,
                           training_capacitance_pF (n_train, k), training_done (n_train,),
                           sequence_capacitance_pF (n_seq, k), sequence_done (n_seq,),
                           training_wall_s, sequence_wall_s (per pose, s)

Capacitances of a pose whose simulation failed are NaN with ``done`` set; the fit skips
such training poses and the scores leave such sequence poses out (both logged).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
import tomllib
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable

import h5py
import numpy as np

from mscap.calibration.reconstruction import Features, PoseErrors, fit, point_errors, score
from mscap.design.readback import reading_variance
from mscap.errors import CalibrationError, MscapError
from mscap.geometry.layout import Layout
from mscap.scene.calibration import CalibrationSettings, family_poses
from mscap import farm

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["CalibrationError", "Candidate", "FAMILIES", "families", "physics_sha256", "family", "targets",
           "simulate_family", "read_cache", "evaluate", "DesignScore"]

log = logging.getLogger(__name__)

FORMAT = "mscap-calibration"
SCHEMA_VERSION = 2  # 2: designs keyed by their outlines alone
FAMILIES = ("training", "sequence")


@dataclass(frozen=True, eq=False)
class Candidate:
    """A layout to calibrate: ``label`` names it in tables and figures."""

    label: str
    outlines: tuple[np.ndarray, ...]
    #: A :class:`mscap.fabrication.wired.Wiring`: read the sensor as wired (its nets'
    #: mutual capacitances), not its plates.
    wiring: object = None

    @property
    def k(self) -> int:
        return len(self.outlines)

    @property
    def key(self) -> str:
        """HDF5 group name of the design: the hash of its outlines alone, so a changed layout
        is a new entry and the same layout under another label (a run's design calibrated
        by the multi-start, then by `mscap calibrate` as "(optimised)") is simulated once."""
        h = hashlib.sha256()
        for outline in self.outlines:
            h.update(np.ascontiguousarray(outline, dtype=float).tobytes())
        if self.wiring is not None:
            return f"wiring_{self.wiring.key}_{h.hexdigest()[:16]}"
        return f"layout_{h.hexdigest()[:16]}"


def settings(scene: Scene) -> CalibrationSettings:
    """The scene's calibration settings, or a :class:`CalibrationError` naming the file."""
    if scene.calibration is None:
        raise CalibrationError(f"{scene.path}: no [calibration] section (the pose family to "
                               "train and evaluate on); see docs/calibration.md")
    return scene.calibration


def physics_sha256(scene: Scene) -> str:
    """Hash of everything in the scene that can change a simulated capacitance: the
    scene's data without the tables that cannot (``[calibration]``, ``[optimizer]``,
    ``[multistart]``, name and description)."""
    data = tomllib.loads(scene.source)
    for key in ("calibration", "optimizer", "multistart", "name", "description"):
        data.pop(key, None)
    text = json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def families(scene: Scene) -> tuple[str, ...]:
    """The pose sets to simulate: training, sequence and ``reference_<pose>`` if the
    calibration reads a reference pose (named by the pose: another reference is another
    set, the cached ones stay valid)."""
    cal = settings(scene)
    return FAMILIES + ((f"reference_{cal.reference}",) if cal.reference else ())


def family(scene: Scene, which: str) -> tuple:
    """The training, sequence or reference poses of the scene's calibration."""
    cal = settings(scene)
    if which.startswith("reference_"):
        return tuple(p for p in scene.poses if p.name == which[len("reference_"):])
    template = next(p for p in scene.poses if p.name == cal.pose)
    return family_poses(template, cal.parameters, getattr(cal, which), which)


def targets(scene: Scene, which: str) -> tuple[np.ndarray, int]:
    """``(n, n_out)`` reconstruction targets of a family and the point dimension: the
    posed object's vertices (object frame, mm; dim 3) or the parameters (dim 1)."""
    cal = settings(scene)
    if cal.target == "parameters":
        return np.array(getattr(cal, which), dtype=float), 1
    poses = family(scene, which)
    return np.array([p.vertex_positions(1.0).ravel() for p in poses]), 3


# ---------------------------------------------------------------- simulation (workers)
@dataclass(frozen=True, eq=False)
class _Task:
    design: int
    which: str
    start: int
    stop: int


def _simulate_chunk(scene: Scene, design: Candidate, poses: tuple, mesh=None) -> tuple[np.ndarray, np.ndarray]:
    """Capacitances ``(n, k)`` and wall times of ``poses`` on one mesh of ``design``.
    A chunk that fails is redone pose by pose so only the failing poses are lost (NaN)."""
    from mscap.mesh.layered import mesh_sheet
    from mscap.fem.simulate import simulate
    from mscap.scene.sizing import sheet_for

    sheet = sheet_for(scene, Layout(design.outlines))  # sized for its plates
    if design.wiring is not None:
        from mscap.fabrication.wired import readings, wired_mesh
        mesh = mesh or wired_mesh(sheet, design.wiring)
    else:
        mesh = mesh or mesh_sheet(sheet)
    try:
        if design.wiring is not None:
            return readings(scene, sheet, design.wiring, mesh, poses=poses)
        sim = simulate(scene, mesh=mesh, poses=poses, sheet=sheet)
        return sim.capacitance_pF, np.array([r.elastic_s + r.electrostatic_s for r in sim.poses])
    except MscapError as exc:
        if len(poses) == 1:
            log.warning("design %s, pose %s failed: %s", design.label, poses[0].name, exc)
            return np.full((1, design.k), np.nan), np.zeros(1)
    parts = [_simulate_chunk(scene, design, (p,), mesh) for p in poses]
    return np.vstack([c for c, _ in parts]), np.concatenate([w for _, w in parts])


def _work(scene: Scene, designs, poses_of):
    def work(task: _Task):
        poses = poses_of[task.which][task.start:task.stop]
        return task, *_simulate_chunk(scene, designs[task.design], poses)
    return work


# ---------------------------------------------------------------- cache (master)
#: At most this many designs in a cache (the multi-start calibrates a few per k; a file that
#: holds more is not one mscap wrote, and checking it would take long).
MAX_CACHED_DESIGNS = 10_000
_TABLES = ("capacitance_pF", "done", "wall_s")


def cache_problem(cache: h5py.File) -> str | None:
    """What is wrong with an opened calibration cache, from its declarations (nothing but
    each design's ``k + 1`` outline offsets is read), or ``None``: every design group
    with its label, k, outlines and, per pose set, the three tables of the same length."""
    from mscap.infile import dataset_problem
    from mscap.scene.settings import MAX_CAPACITORS

    designs = cache.get("designs")
    if not isinstance(designs, h5py.Group):
        return "no group /designs"
    if len(designs) > MAX_CACHED_DESIGNS:
        return f"/designs holds {len(designs)} members; at most {MAX_CACHED_DESIGNS}"
    for key, g in designs.items():
        where = f"/designs/{key[:40]!r}"
        if not isinstance(g, h5py.Group):
            return f"{where} is not a group"
        k = g.attrs.get("k")
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_CAPACITORS:
            return f"{where}: attribute 'k' is {str(k)[:40]!r}, not an integer in [1, {MAX_CAPACITORS}]"
        label = g.attrs.get("label")
        if not isinstance(label, (str, bytes)) or len(label) > 1000:
            return f"{where}: attribute 'label' is not a text of at most 1000 characters"
        problem = (dataset_problem(g.get("outline_points_mm"), "outline_points_mm", "f", 2)
                   or dataset_problem(g.get("outline_offsets"), "outline_offsets", "iu", 1))
        if problem:
            return f"{where}: {problem}"
        points, offsets = g["outline_points_mm"], g["outline_offsets"]
        if points.shape[1] != 2 or offsets.shape != (k + 1,):
            return f"{where}: outlines {points.shape} with offsets {offsets.shape} for k = {k}"
        offsets = offsets[()]
        if offsets[0] != 0 or offsets[-1] != len(points) or np.any(np.diff(offsets) < 3):
            return f"{where}: outline offsets {offsets.tolist()[:8]} do not split {len(points)} points into {k} polygons"
        sets = {name[:-len(f"_{table}")] for name in g for table in _TABLES if name.endswith(f"_{table}")}
        for which in sorted(sets):
            kinds = {"capacitance_pF": ("f", 2), "done": ("b", 1), "wall_s": ("f", 1)}
            for table, (kind, ndim) in kinds.items():
                problem = dataset_problem(g.get(f"{which}_{table}"), f"{which}_{table}", kind, ndim)
                if problem:
                    return f"{where}: {problem}"
            n = len(g[f"{which}_done"])
            if g[f"{which}_capacitance_pF"].shape != (n, k) or g[f"{which}_wall_s"].shape != (n,):
                return (f"{where}: {which} tables {g[f'{which}_capacitance_pF'].shape}, {(n,)}, "
                        f"{g[f'{which}_wall_s'].shape} do not agree with k = {k}")
    return None


def _text(attrs, name: str) -> str:
    """A scalar attribute as text (at most 100 characters); ``""`` for anything else (an
    array, a compound: a file mscap did not write)."""
    value = attrs.get(name)
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, (str, int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        return str(value)[:100]
    return ""


def _open_cache(path, scene: Scene) -> h5py.File:
    """The calibration cache at ``path``, locked for this process like a results file
    (:mod:`mscap.outfile`: never through a link, never truncated while another
    process holds it); started over when it holds another scene or pose family."""
    from mscap.outfile import ResultsFile, WriteLock, check_output_path

    physics, fam = physics_sha256(scene), settings(scene).family_sha256()
    lock = WriteLock(check_output_path(path))
    try:
        f = ResultsFile(lock, "w" if lock.empty else "r+")
    except OSError as exc:
        lock.close()
        raise CalibrationError(f"{path}: cannot open the calibration cache ({exc})") from None
    if not lock.empty:
        try:
            ours = _text(f.attrs, "format") == FORMAT
            stale = (_text(f.attrs, "schema_version") != str(SCHEMA_VERSION)
                     or _text(f.attrs, "physics_sha256") != physics or _text(f.attrs, "family_sha256") != fam)
            problem = cache_problem(f) if ours and not stale else None
        except (KeyError, OSError, RuntimeError, ValueError, TypeError) as exc:  # HDF5 could not read it
            from mscap.infile import one_line

            ours, stale, problem = True, False, one_line(exc)
        if not ours:
            f.close()
            raise CalibrationError(f"{path} is not an mscap calibration cache; give another --cache")
        if problem:
            f.close()
            raise CalibrationError(f"{path}: a damaged calibration cache ({problem}); delete it (the "
                                   f"calibration makes it again) or give another --cache")
        if not stale:
            return f
        log.warning("%s: cache of another scene or pose family; starting it over", path)
        h5py.File.close(f)  # the file only: the lock stays held while it is truncated
        f = ResultsFile(lock, "w")
    f.attrs.update({"format": FORMAT, "schema_version": SCHEMA_VERSION, "physics_sha256": physics,
                    "family_sha256": fam})
    f.create_group("designs")
    return f


def _design_group(cache: h5py.File, design: Candidate, sizes: dict[str, int]) -> h5py.Group:
    designs = cache["designs"]
    if design.key in designs:
        g = designs[design.key]
    else:
        g = designs.create_group(design.key)
        g.attrs.update({"label": design.label, "k": design.k})
        points = np.vstack(design.outlines)
        offsets = np.cumsum([0] + [len(o) for o in design.outlines])
        g.create_dataset("outline_points_mm", data=points)
        g.create_dataset("outline_offsets", data=offsets.astype(np.int64))
    for which, n in sizes.items():
        if f"{which}_done" in g:
            continue
        g.create_dataset(f"{which}_capacitance_pF", data=np.full((n, design.k), np.nan))
        g.create_dataset(f"{which}_done", data=np.zeros(n, dtype=bool))
        g.create_dataset(f"{which}_wall_s", data=np.zeros(n))
    cache.flush()
    return g


def _chunks(todo: np.ndarray, size: int) -> list[tuple[int, int]]:
    """Runs of at most ``size`` consecutive missing poses (``todo`` is a boolean mask)."""
    out, i, n = [], 0, len(todo)
    while i < n:
        if not todo[i]:
            i += 1
            continue
        j = i
        while j < n and todo[j] and j - i < size:
            j += 1
        out.append((i, j))
        i = j
    return out


def simulate_family(scene: Scene, designs: list[Candidate], cache_path, comm=None,
                    progress: Callable[[str], None] | None = None) -> bool | None:
    """Simulate every design's training and sequence poses that the cache lacks.

    Under ``mpirun`` rank 0 writes the cache and the other ranks simulate; with one rank
    everything runs here. Returns on every rank when done (or when stopped by SIGTERM,
    after which a rerun completes the rest): on rank 0 whether every pose is simulated
    (``False``: stopped), ``None`` on the others.
    """
    # MPI before any file is open: a singleton MPI start forks OpenMPI's orted, which
    # would inherit the open cache and hold its HDF5 lock for the life of the process.
    from mpi4py import MPI

    say = progress or (lambda m: None)
    comm = comm or MPI.COMM_WORLD
    names = families(scene)
    poses_of = {which: family(scene, which) for which in names}

    def master(execute, stop) -> bool:
        cache = _open_cache(cache_path, scene)
        try:
            sizes = {which: len(poses_of[which]) for which in names}
            groups = [_design_group(cache, d, sizes).name for d in designs]
            n_workers = max(comm.Get_size() - 1, 1)
            missing = [(i, which, ~cache[g][f"{which}_done"][()]) for i, g in enumerate(groups) for which in names]
            # about two chunks per worker, but at least 4 poses each (a chunk meshes once)
            size = max(4, math.ceil(sum(int(m.sum()) for *_, m in missing) / (2 * n_workers)))
            tasks = [_Task(i, which, a, b) for i, which, m in missing for a, b in _chunks(m, size)]
            total = sum(t.stop - t.start for t in tasks)
            say(f"{cache_path}: {len(designs)} designs × ({sizes['training']} training + "
                f"{sizes['sequence']} sequence poses"
                + "".join(f" + reference pose {w[len('reference_'):]}" for w in names if w.startswith("reference_"))
                + f"); {total} poses to simulate in {len(tasks)} chunks "
                f"on {n_workers} worker{'s' if n_workers > 1 else ''}")
            started, done = time.perf_counter(), 0

            def record(result) -> None:
                nonlocal done
                task, capacitance, wall = result
                g = cache[groups[task.design]]
                g[f"{task.which}_capacitance_pF"][task.start:task.stop] = capacitance
                g[f"{task.which}_wall_s"][task.start:task.stop] = wall
                g[f"{task.which}_done"][task.start:task.stop] = True
                cache.flush()
                done += task.stop - task.start
                failed = int(np.isnan(capacitance).any(axis=1).sum())
                eta = (time.perf_counter() - started) / done * (total - done)
                say(f"[{done}/{total}] {designs[task.design].label} {task.which} poses {task.start}-"
                    f"{task.stop - 1}: {wall.sum():.1f} s" + (f", {failed} failed" if failed else "")
                    + f"; ETA {eta:.0f} s")

            execute(tasks, record)
            return not stop.requested
        finally:
            cache.close()

    return farm.run(comm, lambda ask: _work(scene, designs, poses_of), master,
                    "stopped: the finished poses are cached; rerun the same command to complete the rest", say)


def read_cache(cache_path, design: Candidate, names=FAMILIES) -> dict[str, np.ndarray]:
    """A design's cached capacitances and wall times of the pose sets ``names``."""
    with h5py.File(cache_path, "r") as f:
        if design.key not in f["designs"]:
            raise CalibrationError(f"{cache_path}: design {design.label} not simulated yet")
        g = f["designs"][design.key]
        out = {}
        for which in names:
            if f"{which}_done" not in g or not g[f"{which}_done"][()].all():
                raise CalibrationError(f"{cache_path}: design {design.label} has unsimulated "
                                       f"{which} poses; run the calibration again to complete it")
            out[which] = g[f"{which}_capacitance_pF"][()]
            out[f"{which}_wall_s"] = g[f"{which}_wall_s"][()]
        return out


# ---------------------------------------------------------------- scoring (master)
@dataclass(frozen=True, eq=False)
class DesignScore:
    """A design's reconstruction errors over the sequence (``errors``: runs × poses;
    NaN columns for sequence poses that failed to simulate). ``no_signal`` is the mean
    point error per sequence pose of a sensor that tells nothing (always answering the
    mean training pose): errors near it mean the read-outs carry no usable signal."""

    design: Candidate
    errors: PoseErrors
    no_signal: np.ndarray
    training_used: int
    training_failed: int
    samples: int
    sequence_failed: int
    simulation_s: float
    features: Features | None = None  # the map's whitened directions (None: raw read-outs)


def evaluate(scene: Scene, designs: list[Candidate], cache_path, noise=None, seeds=()) -> list[DesignScore]:
    """Fit and score every design from the cache (``noise`` overrides the scene's). With
    ``seeds``, each design's map is scored once per noise seed (the fit does not depend on
    the noise draws) and ``errors`` holds the runs of every seed, seed after seed."""
    cal = settings(scene)
    noise = noise or cal.noise
    train_y, dim = targets(scene, "training")
    seq_y, _ = targets(scene, "sequence")
    scores = []
    for design in designs:
        data = read_cache(cache_path, design, families(scene))
        c_train, c_seq = data["training"], data["sequence"]
        c_ref = None
        if cal.reference:
            c_ref = data[f"reference_{cal.reference}"][0]
            if not (np.isfinite(c_ref).all() and (c_ref > 0).all()):
                raise CalibrationError(f"design {design.label}: the reference pose {cal.reference!r} "
                                       f"has capacitances {c_ref} pF; cannot divide by them")
        ok_train = np.isfinite(c_train).all(axis=1)
        ok_seq = np.isfinite(c_seq).all(axis=1)
        if (~ok_train).any() or (~ok_seq).any():
            log.warning("design %s: %d training and %d sequence poses failed to simulate; left out",
                        design.label, (~ok_train).sum(), (~ok_seq).sum())
        features = c_train[ok_train] if c_ref is None else c_train[ok_train] / c_ref
        noise_std, smoothing = None, cal.smoothing
        if cal.features == "whitened":  # each feature's noise at the family's mean read-out
            noise_std = np.sqrt(reading_variance(features.mean(axis=0), c_ref, noise)[0])
            if not (noise_std > 0).all():  # noise-free read-outs: the interpolant, the limit σ → 0
                noise_std, smoothing = None, 0.0
        model = fit(features, train_y[ok_train], cal.kernel, smoothing, noise_std, cal.min_spread)
        parts = [score(model, c_seq[ok_seq], seq_y[ok_seq], dim, replace(noise, seed=seed), reference_pF=c_ref)
                 for seed in (seeds or (noise.seed,))]
        errors = PoseErrors(np.vstack([e.mean for e in parts]), np.vstack([e.max for e in parts]))
        full_mean = np.full((len(errors.mean), len(c_seq)), np.nan)
        full_max = full_mean.copy()
        full_mean[:, ok_seq], full_max[:, ok_seq] = errors.mean, errors.max
        no_signal = point_errors(train_y[ok_train].mean(axis=0)[None], seq_y, dim).mean(axis=1)
        scores.append(DesignScore(design, PoseErrors(full_mean, full_max), no_signal, int(ok_train.sum()),
                                  int((~ok_train).sum()), len(model.groups), int((~ok_seq).sum()),
                                  float(sum(data[f"{w}_wall_s"].sum() for w in families(scene))),
                                  model.features))
    return scores
