"""Fuzzing the scene loader: every mutation of a shipped scene loads into a ``Scene`` or
stops with an :class:`~mscap.errors.MscapError`, never another exception, a hang or a
blow-up (docs/scenes.md, "Fuzzing the loader").

Each case is a deterministic mutation (seeded by its index) of one of the scenes in
``jobs/``, written to a file and loaded in a worker process that runs under an address
space cap (``RLIMIT_AS``) with a per-case alarm; the workers report, per case, ``"scene"``,
``"error"`` (an MscapError, one line naming the file) or what went wrong.
"""

from __future__ import annotations

import copy
import math
import multiprocessing
import random
import resource
import signal
import tomllib
from collections import Counter
from pathlib import Path

import pytest

from tests.conftest import to_toml

JOBS = Path(__file__).resolve().parents[2] / "jobs"
#: Scenes that load in milliseconds take most cases; the glued ones (0.5-1 s a load,
#: their bend radius and calibration family are checked at load) a few each, the glove
#: (2 s) none.
CHEAP = ("quick", "poking", "poking_quick", "poking_cross", "poking_cross_quick", "grid3x3", "biaxial",
         "biaxial_quick")
GLUED = ("wrist_quick", "joystick_quick", "pneumatic_quick")
CASES_CHEAP, CASES_GLUED = 330, 30
#: Per case: seconds before it counts as a hang, and the address space above the
#: worker's own at the start before it counts as a blow-up.
TIME_LIMIT_S, MEMORY_LIMIT_BYTES = 20, 1 << 30

EXTREMES = [0, -1, 0.0, -0.0, -1.5, 1e-308, 5e-324, 1e-9, 1e9, 1e308, -1e308, math.inf, -math.inf, math.nan,
            2**31, 2**63 - 1, -2**63, 10**6]
OTHER_TYPES = ["text", "", True, False, [], [1, 2], {}, {"a": 1}, [[0.0, 0.0]], 42, 4.2]
NAMES = ["../../escaped_pose", "/tmp/absolute_pose", "x" * 300, "", ".hidden", "a/b", "CON", "pose\u0000nul"]


# ---------------------------------------------------------------- mutations
def _slots(data, path=()):
    """Every (container, key) pair of the document, depth first."""
    items = data.items() if isinstance(data, dict) else enumerate(data)
    for key, value in items:
        yield path + (key,), data, key
        if isinstance(value, (dict, list)):
            yield from _slots(value, path + (key,))


def _pick(rng, data, want=lambda value: True):
    slots = [(p, c, k) for p, c, k in _slots(data) if want(c[k])]
    return rng.choice(slots) if slots else None


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _typo(rng, key: str) -> str:
    i = rng.randrange(len(key))
    return rng.choice([key[:i] + key[i + 1:], key[:i] + key[i] * 2 + key[i + 1:],
                       key[:i] + key[i + 1:i + 2] + key[i:i + 1] + key[i + 2:]]) or "x"


def _range(rng, data):
    slot = _pick(rng, data, _is_number)
    slot[1][slot[2]] = rng.choice(EXTREMES)


def _type(rng, data):
    slot = _pick(rng, data)
    slot[1][slot[2]] = copy.deepcopy(rng.choice(OTHER_TYPES))


def _missing(rng, data):
    slot = _pick(rng, data)
    del slot[1][slot[2]]


def _typo_key(rng, data):
    slot = _pick(rng, data)
    container, key = slot[1], slot[2]
    if isinstance(container, dict):
        container[_typo(rng, key)] = container.pop(key)
    else:
        container.append(copy.deepcopy(container[key]))


def _unknown_key(rng, data):
    slot = _pick(rng, data, lambda value: isinstance(value, dict)) or ((), {"": data}, "")
    slot[1][slot[2]]["bogus_key"] = rng.choice(EXTREMES + OTHER_TYPES)


def _nested(rng, data):
    """A table becomes a scalar, a list or a list of itself; a list of tables a table."""
    slot = _pick(rng, data, lambda value: isinstance(value, (dict, list)))
    container, key = slot[1], slot[2]
    value = container[key]
    container[key] = rng.choice([1.0, "table", [value], [], {}, value if isinstance(value, dict) else
                                 (value[0] if value else {})])


def _reference(rng, data):
    """A name another entry refers to (material, object, calibration pose) goes missing."""
    slots = [s for s in _slots(data) if s[2] in ("material", "fill", "object", "pose", "reference", "rest")]
    if not slots:
        return _missing(rng, data)
    _, container, key = rng.choice(slots)
    container[key] = rng.choice(["nonexistent", "", "../../etc/passwd", "/dev/zero", "."])


def _count(rng, data):
    slot = _pick(rng, data, lambda value: isinstance(value, int) and not isinstance(value, bool))
    if slot is None:
        return _range(rng, data)
    slot[1][slot[2]] = rng.choice([2**63 - 1, 10**9, 10**6, 100_000, 2**31, 0, -1])


def _pose_name(rng, data):
    poses = data.get("poses") or [{"kind": "free"}]
    data["poses"] = poses
    poses[rng.randrange(len(poses))]["name"] = rng.choice(NAMES)


def _grid_count(rng, data):
    """A calibration axis, a [capacitors.grid] or a waypoint list blown up."""
    if "calibration" in data and isinstance(data["calibration"].get("training"), dict):
        axes = data["calibration"]["training"]
        name = rng.choice(sorted(axes))
        axes[name] = [0.0, 1.0, rng.choice([10**6, 10**9, 2**63 - 1])] if rng.random() < 0.5 else \
            [0.0, math.nan, 3]
    else:
        data["capacitors"].pop("outlines_mm", None)
        data["capacitors"]["grid"] = {"shape": rng.choice(["square", "disk", "rounded_square"]),
                                      "rows": rng.choice([1, 10**6, 2**31]), "columns": rng.choice([1, 1000]),
                                      "size_mm": rng.choice([1.0, 1e308, 1e-300]), "pitch_mm": 2.0,
                                      "corner_radius_mm": 0.1}


TREE_MUTATIONS = {"range": _range, "type": _type, "missing key": _missing, "typo'd key": _typo_key,
                  "unknown key": _unknown_key, "nested-table damage": _nested, "missing reference": _reference,
                  "huge count": _count, "pose name": _pose_name, "grid/family size": _grid_count}


def _file_mutation(rng, text: str) -> tuple[str, bytes]:
    """Damage to the file itself."""
    kind = rng.choice(["empty", "binary", "truncated", "byte flips", "utf-16", "nul", "long line"])
    data = text.encode()
    if kind == "empty":
        return kind, b""
    if kind == "binary":
        return kind, bytes(rng.randrange(256) for _ in range(rng.choice([1, 64, 4096])))
    if kind == "truncated":
        return kind, data[:rng.randrange(len(data))]
    if kind == "byte flips":
        raw = bytearray(data)
        for _ in range(rng.choice([1, 3, 20])):
            raw[rng.randrange(len(raw))] = rng.randrange(256)
        return kind, bytes(raw)
    if kind == "utf-16":
        return kind, text.encode("utf-16")
    if kind == "nul":
        i = rng.randrange(len(data))
        return kind, data[:i] + b"\0" + data[i:]
    return kind, data + b"\nname = \"" + b"x" * 100_000 + b"\"\n"


def make_case(index: int, directory: Path) -> tuple[str, Path]:
    """Case ``index``: its class and the file it wrote (deterministic in ``index``)."""
    rng = random.Random(index)
    names = CHEAP if index < CASES_CHEAP else GLUED
    base = JOBS / f"{names[index % len(names)]}.toml"
    text = base.read_text()
    path = directory / f"case{index:04d}.toml"
    if rng.random() < 0.1:
        kind, raw = _file_mutation(rng, text)
        path.write_bytes(raw)
        return "file: " + kind, path
    data = tomllib.loads(text)
    kind = rng.choice(sorted(TREE_MUTATIONS))
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        try:
            TREE_MUTATIONS[kind](rng, data)
        except (TypeError, KeyError, IndexError, AttributeError, ValueError):
            pass  # this mutation did not apply to what an earlier one left; keep the rest
    if not isinstance(data, dict):
        data = {}
    path.write_text(to_toml(data))
    return kind, path


# ---------------------------------------------------------------- the workers
def _limit() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    used = _address_space()
    cap = used + MEMORY_LIMIT_BYTES
    resource.setrlimit(resource.RLIMIT_AS, (cap if hard == resource.RLIM_INFINITY else min(cap, hard), hard))


def _address_space() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * resource.getpagesize()


def _timeout(signum, frame):
    raise TimeoutError


def load_case(path: Path) -> tuple[str, str]:
    """``("scene", "")``, ``("error", message)`` or what else happened."""
    from mscap.errors import MscapError
    from mscap.scene import load_scene

    signal.signal(signal.SIGALRM, _timeout)
    signal.alarm(TIME_LIMIT_S)
    try:
        load_scene(path)
        return "scene", ""
    except MscapError as exc:
        return "error", str(exc)
    except TimeoutError:
        return "hang", f"over {TIME_LIMIT_S} s"
    except MemoryError:
        return "blow-up", f"over {MEMORY_LIMIT_BYTES >> 20} MB"
    except Exception as exc:  # noqa: BLE001 - the point: any other exception is a finding
        return "traceback", f"{type(exc).__name__}: {exc}"[:300]
    finally:
        signal.alarm(0)


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    """Every case's (class, file, outcome, detail)."""
    directory = tmp_path_factory.mktemp("fuzz")
    cases = [make_case(i, directory) for i in range(CASES_CHEAP + CASES_GLUED)]
    import mscap.scene.loader  # noqa: F401 - imported once, before the fork
    context = multiprocessing.get_context("fork")
    with context.Pool(2, initializer=_limit, maxtasksperchild=50) as pool:
        results = pool.map(load_case, [path for _, path in cases], chunksize=4)
    return [(kind, path, outcome, detail) for (kind, path), (outcome, detail) in zip(cases, results)]


def test_every_case_is_a_scene_or_a_one_line_mscap_error(outcomes):
    bad = [f"{path.name} ({kind}): {outcome}: {detail}" for kind, path, outcome, detail in outcomes
           if outcome not in ("scene", "error")]
    assert not bad, "\n".join(bad)
    for kind, path, outcome, detail in outcomes:
        if outcome == "error":
            assert detail.startswith(f"{path}: ") and "\n" not in detail, (kind, detail)
    # Every class ran; most cases break the scene, and some (a value still in range) do not.
    counts = Counter(kind.split(":")[0] for kind, *_ in outcomes)
    assert set(TREE_MUTATIONS) | {"file"} <= set(counts), counts
    results = Counter(outcome for *_, outcome, _ in outcomes)
    assert results["error"] > len(outcomes) / 2 and results["scene"] > 0, results
