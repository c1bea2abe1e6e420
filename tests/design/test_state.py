"""Stopping an optimisation and resuming it (mscap.design.state): a start stopped at any
iteration, its state through an HDF5 file, and resumed ends where the uninterrupted start
ends: the same events and steps, J to 1e-7 (measured 3e-9) and the controls to 1e-4 mm
(measured 2e-6), across a remesh and a control refinement."""

from __future__ import annotations

import copy

import h5py
import numpy as np
import pytest

from mscap.design import optimizer
from mscap.design.optimizer import optimize, resumed_design
from mscap.design.pipeline import build_design
from mscap.design.state import read_state, write_state
from mscap.scene import load_scene
from tests.conftest import to_toml
from tests.design.test_optimize import POKES
from tests.scenes import scene_dict

pytest.importorskip("igl")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("state") / "pokes.toml"
    path.write_text(to_toml(scene_dict(**copy.deepcopy(POKES))))
    return load_scene(path)


def test_a_start_stopped_anywhere_and_resumed_ends_where_it_would_have(scene, tmp_path, monkeypatch):
    # one remesh after the first step, then a cascade level: the design is rebuilt by
    # replaying both (its layout and control counts, then the refinement at its q)
    calls = iter(range(1000))
    monkeypatch.setattr(optimizer, "needs_remesh", lambda *args: next(calls) == 0)
    states = []
    whole = optimize(build_design(scene), max_iterations=3, cascade_levels=1,
                     keep=lambda state: states.append(state()))
    events = [r.event for r in whole.history]
    assert "remesh" in events and "cascade" in events, events
    assert len(states) >= 6
    monkeypatch.setattr(optimizer, "needs_remesh", lambda *args: False)  # the remesh is behind every state below
    checked = 0
    for i, state in enumerate(states):
        if state.iteration < 1 or (i % 2 and i != len(states) - 1):
            continue  # every other state after the remesh, and the last
        with h5py.File(tmp_path / f"state{i}.h5", "w") as f:
            write_state(f.create_group("start"), state)
        with h5py.File(tmp_path / f"state{i}.h5", "r") as f:
            back = read_state(f["start"])
        assert len(back.history) == len(state.history) and back.level == state.level
        resumed = optimize(resumed_design(scene, scene.sheet, back), max_iterations=3, cascade_levels=1, resume=back)
        assert [r.event for r in resumed.history] == events, (i, [r.event for r in resumed.history])
        assert resumed.iterations == whole.iterations and resumed.reason == whole.reason
        np.testing.assert_allclose([r.J for r in resumed.history], [r.J for r in whole.history], rtol=1e-7,
                                   err_msg=f"resumed from state {i}")
        # the equilibria are found again from their displacements (rest + u, to round-off, then
        # Newton to its tolerance): J agrees to 3e-9 here, the controls to 2e-6 mm after 8 steps
        np.testing.assert_allclose(resumed.evaluation.q, whole.evaluation.q, atol=1e-4)
        np.testing.assert_allclose(resumed.initial.capacitance_pF, whole.initial.capacitance_pF, rtol=0)
        checked += 1
    assert checked >= 2


def test_a_state_of_another_design_is_refused(scene):
    import dataclasses

    states = []
    optimize(build_design(scene), max_iterations=1, cascade_levels=0, keep=lambda state: states.append(state()))
    state = states[-1]
    resumed_design(scene, scene.sheet, state).close()  # its own fits
    for change, message in ((dict(q=state.q[:-1]), "q has shape"),
                            (dict(displacements=state.displacements[:-1]), "the equilibria has shape"),
                            (dict(displacements=tuple(None if u is None else u[:-1] for u in state.displacements)),
                             "an equilibrium has shape")):
        with pytest.raises(ValueError, match=message):
            resumed_design(scene, scene.sheet, dataclasses.replace(state, **change))
