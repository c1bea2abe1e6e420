"""A calibration cache is hostile until checked (issue 48): a cache that matches the scene
but whose design tables are of the wrong type, shape or size, or declare a bomb, is one
``CalibrationError`` naming the file and the object, before a table is read; one whose
attributes are not what mscap writes is not taken for a cache. The honest cache is made by
the code itself (no pose is simulated)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from mscap.calibration.service import MAX_CACHED_DESIGNS, CalibrationError, Candidate, _design_group, _open_cache
from mscap.scene import load_scene
from tests.calibration.test_calibration import calibration_scene
from tests.conftest import within


def _replace(table, data=None, **kwargs):
    def mutate(g):
        del g[table]
        g.create_dataset(table, data=data, **kwargs)
    return mutate


def _attr(name, value):
    def mutate(g):
        g.attrs[name] = value
    return mutate


def _bomb(g):
    """A few kB declaring 1e9 × 2 capacitances (16 GB once read)."""
    del g["training_capacitance_pF"]
    g.create_dataset("training_capacitance_pF", shape=(1_000_000_000, 2), dtype="f8", chunks=(1 << 16, 2),
                     compression="gzip")


def _many_designs(g):
    designs = g.parent
    for i in range(MAX_CACHED_DESIGNS):
        designs.create_group(f"d{i}")


#: mutation of the design group -> words of the refusal
MUTATIONS = {
    "k as text": (_attr("k", "two"), "attribute 'k' is 'two'"),
    "k too large": (_attr("k", 2**40), "not an integer in [1, "),
    "label an array": (_attr("label", np.arange(3)), "attribute 'label' is not a text"),
    "points as strings": (_replace("outline_points_mm", np.array(["a", "b"], dtype=object), dtype=h5py.string_dtype()),
                          "dataset 'outline_points_mm' has 1 dimensions"),
    "offsets beyond the points": (_replace("outline_offsets", np.array([0, 4, 900])), "do not split"),
    "done as floats": (_replace("training_done", np.zeros(6)), "dataset 'training_done' holds float64, not booleans"),
    "capacitance of another k": (_replace("training_capacitance_pF", np.zeros((6, 3))), "do not agree with k = 2"),
    "a table missing": (lambda g: g.__delitem__("sequence_wall_s"), "no dataset 'sequence_wall_s'"),
    "a table alone": (lambda g: g.create_dataset("extra_wall_s", data=np.zeros(2)), "no dataset 'extra_capacitance_pF'"),
    "a compression bomb": (_bomb, "declares (1000000000, 2)"),
    "a design that is a dataset": (lambda g: g.parent.create_dataset("x", data=1), "'x' is not a group"),
    "too many designs": (_many_designs, f"holds {MAX_CACHED_DESIGNS + 1} members"),
}


@pytest.fixture
def honest(write_scene, tmp_path):
    scene = load_scene(write_scene(calibration_scene()))
    base = tuple(np.array(o) for o in scene.layout.outlines)
    path = tmp_path / "cache.h5"
    cache = _open_cache(path, scene)
    try:
        g = _design_group(cache, Candidate("given", base), {"training": 6, "sequence": 9})
        key = g.name
    finally:
        cache.close()
    _open_cache(path, scene).close()  # honest: opened again as it is
    return scene, path, key


@pytest.mark.parametrize("name", sorted(MUTATIONS))
def test_a_damaged_cache_is_one_error_naming_it(honest, name):
    scene, path, key = honest
    mutate, words = MUTATIONS[name]
    with h5py.File(path, "r+") as f:
        mutate(f[key])
    with within(20), pytest.raises(CalibrationError) as err:
        _open_cache(path, scene)
    message = str(err.value)
    assert message.startswith(f"{path}: a damaged calibration cache (") and words in message, message
    assert message.endswith("delete it (the calibration makes it again) or give another --cache")
    assert "\n" not in message


@pytest.mark.parametrize("value", [np.array(["mscap-calibration"] * 2, dtype=object), 3.5])
def test_a_format_attribute_that_is_not_text_is_not_a_cache(honest, value):
    scene, path, _ = honest
    with h5py.File(path, "r+") as f:
        f.attrs["format"] = value
    with pytest.raises(CalibrationError, match="is not an mscap calibration cache"):
        _open_cache(path, scene)
