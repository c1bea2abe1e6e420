"""Shared fixtures: small scenes written from Python dicts."""

from __future__ import annotations

import copy
import json
import math
import re
import signal
from contextlib import contextmanager

import numpy as np
import pytest

from mscap.mesh.triangulate import TriMesh
from mscap.service.store import HISTORY_COLUMNS, RunRecord


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else "inf" if v > 0 else "-inf"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):  # a table inside an array or a value: inline
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    return repr(v)


def to_toml(data: dict, prefix: str = "") -> str:
    """Enough of a TOML writer for test scenes: scalars (NaN and inf too), arrays, tables,
    arrays of tables, keys that need quotes."""
    lines, nested = [], []
    for key, value in data.items():
        full = f"{prefix}.{_key(key)}" if prefix else _key(key)
        if isinstance(value, dict):
            nested.append(f"\n[{full}]\n" + to_toml(value, full))
        elif isinstance(value, list) and value and all(isinstance(x, dict) for x in value):
            nested.extend(f"\n[[{full}]]\n" + to_toml(x, full) for x in value)
        else:
            lines.append(f"{_key(key)} = {_value(value)}")
    return "\n".join(lines) + "".join(nested) + "\n"


def _layer(name, kind, t, material, fill=None):
    layer = {"name": name, "kind": kind, "thickness_mm": t, "material": material}
    if fill:
        layer["fill"] = fill
    return layer


SMALL_SCENE = {
    "name": "small",
    "sheet": {"width_mm": 30.0, "height_mm": 20.0},
    "materials": {
        "clear": {"youngs_modulus_MPa": 0.57, "poisson_ratio": 0.47, "relative_permittivity": 2.84},
        "carbon": {"youngs_modulus_MPa": 1.1, "poisson_ratio": 0.47, "relative_permittivity": 2.84},
    },
    "layers": [
        _layer("protective_bottom", "dielectric", 0.14, "clear"),
        _layer("bottom_plates", "conductive", 0.07, "carbon", "clear"),
        _layer("dielectric", "dielectric", 0.14, "clear"),
        _layer("top_plates", "conductive", 0.07, "carbon", "clear"),
        _layer("protective_top", "dielectric", 0.14, "clear"),
    ],
    "capacitors": {
        "min_gap_mm": 1.0,
        "outlines_mm": [
            [[3.0, 4.0], [13.0, 4.0], [13.0, 16.0], [3.0, 16.0]],
            [[17.0, 5.0], [27.0, 5.0], [25.0, 15.0], [19.0, 16.0]],
        ],
    },
    "mesh": {"edge_length_mm": 3.0, "edge_length_outline_mm": 0.5, "grading_distance_mm": 3.0},
    "poses": [{"name": "rest", "kind": "free"}],
}


@pytest.fixture
def small_scene_dict():
    """A fresh, valid, fast-to-mesh scene as a dict (mutate freely)."""
    return copy.deepcopy(SMALL_SCENE)


@pytest.fixture
def write_scene(tmp_path):
    """``write_scene(dict) -> path`` of a TOML file holding it."""
    def write(data: dict, name: str = "scene.toml"):
        path = tmp_path / name
        path.write_text(to_toml(data))
        return path
    return write


@pytest.fixture
def free_poses_scene(small_scene_dict, write_scene):
    """``free_poses_scene(k_max)``: the small scene with three free poses (rest, a, b) and
    a multi-start over k = 2..k_max, 3 starts per k (store, selection and plot tests)."""
    from mscap.scene import load_scene

    def build(k_max: int):
        small_scene_dict["multistart"] = {"k_min": 2, "k_max": k_max, "starts_per_k": 3, "plateau_tol": 0.05}
        small_scene_dict["poses"] = [{"name": name, "kind": "free"} for name in ("rest", "a", "b")]
        return load_scene(write_scene(small_scene_dict))
    return build


def grid_trimesh(nx, ny, width, height, capacitor_of_centroid, jitter=0.0, seed=0):
    """A structured triangulation, interior vertices jittered by ``jitter`` cell sizes."""
    xs, ys = np.meshgrid(np.linspace(0, width, nx + 1), np.linspace(0, height, ny + 1))
    points = np.c_[xs.ravel(), ys.ravel()]
    inner = (points[:, 0] > 0) & (points[:, 0] < width) & (points[:, 1] > 0) & (points[:, 1] < height)
    cell = np.array([width / nx, height / ny])
    points[inner] += jitter * cell * np.random.default_rng(seed).uniform(-1, 1, (inner.sum(), 2))
    index = np.arange(len(points)).reshape(ny + 1, nx + 1)
    a, b, c, d = (index[:-1, :-1].ravel(), index[:-1, 1:].ravel(),
                  index[1:, 1:].ravel(), index[1:, :-1].ravel())
    triangles = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    owner = capacitor_of_centroid(points[triangles].mean(axis=1)).astype(np.int64)
    return TriMesh(points, triangles, owner)


def synthetic_record(k: int, seed: int, init: str = "random", scale: float = 1.0, rank: int = 1) -> RunRecord:
    """A successful multi-start record (store and plot tests) with irrational-looking
    numbers: a round trip must keep every bit."""
    rng = np.random.default_rng(seed)
    n_rows = 5
    outlines = lambda: tuple(rng.random((int(rng.integers(4, 9)), 2)) * 30 for _ in range(k))  # noqa: E731
    history = {name: (np.array(["start", "step", "remesh", "step", "converged"], dtype=object) if kind == "str"
                      else np.arange(n_rows, dtype=kind) if kind == "int64" else rng.random(n_rows) * np.pi)
               for name, kind in HISTORY_COLUMNS.items()}
    return RunRecord(k=k, seed=seed, init=init, status="ok", reason="converged", wall_s=float(rng.random() * 100),
                     iterations=n_rows - 1, rank=rank, poses=("rest", "a", "b"),
                     initial_outlines=outlines(), final_outlines=outlines(),
                     initial_capacitance_pF=50 + rng.random((3, k)),
                     final_capacitance_pF=50 + scale * rng.random((3, k)) * 10, history=history)


@contextmanager
def within(seconds: int):
    """Fail instead of hanging: a blocked open or an endless read is the bug tested for."""
    def expired(signum, frame):
        raise AssertionError(f"still reading after {seconds} s")

    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


#: The longest files first (with their durations under ``make test`` on 2 cores), so that
#: the two workers of ``make test`` (pytest-xdist, a file per worker, in this order:
#: ``--no-loadscope-reorder``) end together; the real-SLURM self-test, which mostly waits
#: for its jobs, runs beside everything else.
LONGEST_FIRST = ("tests/service/test_slurm_real.py",     # 4 min
                 "tests/test_jobs.py",                   # 3.5 min
                 "tests/service/test_multistart.py",     # 2.5 min
                 "tests/mesh/test_shape.py")             # 1.5 min


def pytest_collection_modifyitems(session, config, items):
    """:data:`LONGEST_FIRST`, then the rest in the order collected."""
    def rank(item):
        path = item.nodeid.split("::")[0]
        return LONGEST_FIRST.index(path) if path in LONGEST_FIRST else len(LONGEST_FIRST)
    items.sort(key=rank)
