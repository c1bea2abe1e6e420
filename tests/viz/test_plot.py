"""``mscap plot`` on a synthetic results file (no optimisation runs)."""

from __future__ import annotations

import math
import struct

import pytest

from mscap.cli import main
from mscap.service.selection import RunSummary, select
from mscap.service.store import failed_record, open_store, store_selection, write_run
from mscap.viz.layouts import PANEL_SIZE_IN, grid_shape, panels
from tests.conftest import synthetic_record

DPI = 50


@pytest.fixture
def scene(free_poses_scene):
    return free_poses_scene(k_max=5)


def png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_panels_logic():
    """One panel per k, ascending; only the chosen k flagged; failed-only k empty."""
    runs = [RunSummary("k2_s1_lloyd", 2, True, 1.0, 1.0), RunSummary("k3_s2_lloyd", 3, True, 2.0, 1.0),
            RunSummary("k3_s3_random", 3, True, 1.5, 1.0), RunSummary("k4_s4_lloyd", 4, True, 2.05, 1.0),
            RunSummary("k5_s5_lloyd", 5, False, math.nan, 1.0), RunSummary("k5_s6_random", 5, False, math.nan, 1.0)]
    items = panels(select(runs, 0.05, range(2, 7)))
    assert [p.k for p in items] == [2, 3, 4, 5, 6]
    assert [p.chosen for p in items] == [False, True, False, False, False]
    assert items[1].run_id == "k3_s2_lloyd" and items[1].metric == 2.0
    assert items[1].title == "k = 3, min L1 = 2 pF (chosen)"
    assert items[0].title == "k = 2, min L1 = 1 pF"
    assert items[3].empty and items[3].note == "all 2 runs failed" and "no successful run" in items[3].title
    assert items[4].empty and items[4].note == "no runs"
    from dataclasses import replace

    assert replace(items[1], silent=(2,)).title == "k = 3, min L1 = 2 pF\n2 of 3 plates read the poses (chosen)"
    assert not any(p.chosen for p in panels(select(runs[4:], 0.05)))  # no success: nothing flagged
    assert grid_shape(4) == (2, 4) and grid_shape(3) == (1, 4) and grid_shape(1) == (1, 2)


def test_plot_command(tmp_path, scene, capsys):
    path = tmp_path / "results.h5"
    with open_store(path, scene) as store:
        for k in (2, 3, 4):
            for i in range(2):
                write_run(store, synthetic_record(k, 1000 * k + i, scale=k if k < 4 else 3.0))
        write_run(store, failed_record(5, 5000, "lloyd", "MeshError: bad", wall_s=1.0))
        selection = store_selection(store)
    items = panels(selection)
    assert [p.k for p in items] == [2, 3, 4, 5]
    assert sum(p.chosen for p in items) == 1
    assert next(p for p in items if p.chosen).k == selection.chosen_k
    assert items[-1].empty and items[-1].note == "its only run failed"

    png = tmp_path / "out" / "fig.png"
    assert main(["plot", str(path), "-o", str(png), "--dpi", str(DPI)]) == 0
    assert f"chosen k = {selection.chosen_k}" in capsys.readouterr().out
    rows, cols = grid_shape(len(items))
    assert (rows, cols) == (2, 4)
    width, height = png_size(png)
    assert abs(width - cols * PANEL_SIZE_IN[0] * DPI) <= 2 and abs(height - rows * PANEL_SIZE_IN[1] * DPI) <= 2
    assert png.stat().st_size > 5000  # something was drawn


def test_no_runs(tmp_path, scene, capsys):
    path = tmp_path / "empty.h5"
    open_store(path, scene).close()
    png = tmp_path / "fig.png"
    assert main(["plot", str(path), "-o", str(png)]) == 2
    assert "no finished runs" in capsys.readouterr().err
    assert not png.exists()


def test_not_a_results_file(tmp_path, capsys):
    bogus = tmp_path / "bogus.h5"
    bogus.write_text("not hdf5")
    assert main(["plot", str(bogus), "-o", str(tmp_path / "fig.png")]) == 2
    assert "cannot open as HDF5" in capsys.readouterr().err


def test_a_silent_plate_is_drawn_as_such(tmp_path, scene):
    """The figure's panels carry the plates of each best design that read nothing
    (``report.silent_plates``: their spread over the poses is under half the noise)."""
    from dataclasses import replace

    import numpy as np

    from mscap.viz.layouts import plot_results

    path = tmp_path / "results.h5"
    c = np.array([[0.0, 0.0, 5.0], [1.5, 1.5, 5.0], [3.0, 3.0, 5.0]])  # plate 2 reads 5 pF at every pose
    with open_store(path, scene) as store:
        write_run(store, replace(synthetic_record(3, 3000), final_capacitance_pF=c))
        write_run(store, replace(synthetic_record(2, 2000), final_capacitance_pF=c[:, :2]))
    items = plot_results(path, tmp_path / "fig.png", dpi=DPI)
    assert [(p.k, p.silent) for p in items if not p.empty] == [(2, ()), (3, (2,))]
