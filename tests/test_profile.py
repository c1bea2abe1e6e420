"""mscap.profile: wall time per kind of work (meshing, assembly, factorisation, solve)."""

from __future__ import annotations

import time

import pytest

from mscap import profile


def test_sections_add_up_and_do_not_nest():
    # Compared with the measured durations, not the nominal sleeps: a busy machine oversleeps.
    profile.reset()
    start = time.perf_counter()
    with profile.section("assembly"):
        time.sleep(0.02)
        with profile.section("solve"):  # inside assembly: counted as assembly only
            time.sleep(0.02)
    outer = time.perf_counter() - start
    start = time.perf_counter()
    with profile.section("solve"):
        time.sleep(0.01)
    alone = time.perf_counter() - start
    t = profile.totals()
    assert 0.04 <= t["assembly"] <= outer and 0.01 <= t["solve"] <= alone
    split = profile.split(0.1)
    assert split["other"] == pytest.approx(0.1 - t["assembly"] - t["solve"]) and split["total"] == 0.1
    profile.reset()
    assert sum(profile.totals().values()) == 0.0


def test_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="unknown profile section 'io'"):
        with profile.section("io"):
            pass


def test_a_simulation_reports_every_kind(write_scene, small_scene_dict):
    """The kernels mark themselves: a poked scene spends measurable time in each kind,
    and the kinds never exceed the wall time."""
    from mscap.scene import load_scene
    from mscap.fem.simulate import simulate

    small_scene_dict["poses"].append({"name": "press", "kind": "poke", "center_mm": [8.0, 10.0],
                                      "radius_mm": 5.0, "depth_mm": 2.0, "held_edges": ["x_min", "x_max"]})
    scene = load_scene(write_scene(small_scene_dict))
    profile.reset()
    start = time.perf_counter()
    simulate(scene)
    split = profile.split(time.perf_counter() - start)
    assert all(split[kind] > 0 for kind in profile.KINDS), split
    assert split["other"] >= 0
