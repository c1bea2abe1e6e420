"""The results files of ``mscap run``, ``merge``, ``inspect`` and ``plot`` (issue 21): the
output path rule (no write through a symbolic link, missing directories created) and
damaged or old files read as one-line errors naming the file and the record, never a
traceback. Starts are synthetic (no optimisation runs)."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from mscap.cli import main
from mscap.scene import load_scene
from mscap.service.store import (StoreError, finished_ids, open_store, read_run, read_store, store_selection,
                                 write_run, write_selection)
from tests.conftest import synthetic_record


@pytest.fixture
def scene(free_poses_scene):
    return free_poses_scene(k_max=3)


@pytest.fixture
def synthetic_starts(monkeypatch):
    """``mscap run`` with every start an instant synthetic record, checked (a k's best
    stored unchecked would get a real finer-mesh check on resume)."""
    from dataclasses import replace

    from mscap.service import multistart

    def start(scene, config, *args, **kwargs):
        record = synthetic_record(config.k, config.seed, config.init)
        return replace(record, finer_capacitance_pF=record.final_capacitance_pF * 1.001, error_estimate_wall_s=1.0)
    monkeypatch.setattr(multistart, "run_start", start)


def stored(path, scene, runs=((2, 2000), (3, 3000))) -> None:
    with open_store(path, scene) as store:
        for k, seed in runs:
            write_run(store, synthetic_record(k, seed))
        write_selection(store, store_selection(store))


def one_error(capsys, *names: str) -> str:
    """The single ``mscap: error:`` line on stderr, which must name every one of ``names``."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("mscap: error: "), err
    assert "Traceback" not in err and all(str(n) in lines[0] for n in names), err
    return lines[0]


# ---------------------------------------------------------------- output paths
def test_run_into_a_missing_directory_creates_it(scene, tmp_path, synthetic_starts, capsys):
    out = tmp_path / "out" / "deeper" / "x.h5"
    assert main(["run", str(scene.path), "-o", str(out), "-q"]) == 0
    with read_store(out) as f:
        assert len(finished_ids(f)) == 6  # k = 2, 3, three starts each


@pytest.mark.parametrize("command", ["run", "merge"])
def test_no_output_through_a_symbolic_link(scene, tmp_path, synthetic_starts, capsys, command):
    """A dangling link is not followed (its target is not created) and a link to a file
    is not overwritten, ``--force`` or not: one line naming the link and its target."""
    source = tmp_path / "a.h5"
    stored(source, scene)
    capsys.readouterr()
    target, dangling = tmp_path / "elsewhere.h5", tmp_path / "dangling.h5"
    dangling.symlink_to(target)
    keep = tmp_path / "precious.txt"
    keep.write_text("not results")
    link = tmp_path / "link.h5"
    link.symlink_to(keep)
    args = {"run": ["run", str(scene.path), "-q", "-o"], "merge": ["merge", str(source), "-o"]}[command]
    assert main([*args, str(dangling)]) == 2
    one_error(capsys, dangling, target, "symbolic link")
    assert not target.exists()
    assert main([*args, str(link), "--force"]) == 2
    one_error(capsys, link, keep, "symbolic link")
    assert keep.read_text() == "not results"


def test_plot_replaces_a_link_never_follows_it(scene, tmp_path, capsys):
    """``plot -o link.png`` wrote the figure into the link's target (issue 48); now the figure
    replaces the link, the target is untouched, and a plot that fails leaves nothing."""
    source = tmp_path / "a.h5"
    stored(source, scene)
    keep = tmp_path / "precious.txt"
    keep.write_text("not a figure")
    link = tmp_path / "figs" / "link.png"
    link.parent.mkdir()
    link.symlink_to(keep)
    assert main(["plot", str(source), "-o", str(link)]) == 0
    assert keep.read_text() == "not a figure"
    assert not link.is_symlink() and link.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["plot", str(tmp_path / "missing.h5"), "-o", str(tmp_path / "figs" / "none.png")]) == 2
    assert sorted(p.name for p in link.parent.iterdir()) == ["link.png"]  # no partial file, no temporary


def test_merge_into_a_missing_directory_creates_it(scene, tmp_path, capsys):
    source = tmp_path / "a.h5"
    stored(source, scene)
    out = tmp_path / "merged" / "all.h5"
    assert main(["merge", str(source), "-o", str(out)]) == 0
    with read_store(out) as f:
        assert finished_ids(f) == {"k2_s2000_random", "k3_s3000_random"}


# ---------------------------------------------------------------- damaged files
def damage(path, how: str) -> str:
    """Damage the results file ``path`` as ``how`` says; returns the record named."""
    with h5py.File(path, "r+") as f:
        g = f["runs/k3_s3000_random"]
        if how == "dataset":
            del g["final_capacitance_pF"]
            return "final_capacitance_pF"
        if how == "attribute":
            del g.attrs["metric_pF"]
            return "metric_pF"
        if how == "history":
            del g["history/J"]
            return "history/J"
        f.attrs["scene_toml"] = "name = [unclosed"
        return "scene_toml"


@pytest.mark.parametrize("how", ["dataset", "attribute", "history", "scene"])
def test_damaged_files_give_one_line_errors(scene, tmp_path, capsys, how):
    """inspect (all views), plot and merge check the file before any work: a damaged run
    or stored scene is one line naming the file and the record (was a KeyError or
    TOMLDecodeError traceback); merge writes nothing."""
    path = tmp_path / "r.h5"
    stored(path, scene)
    record = damage(path, how)
    names = (path, record) + (() if how == "scene" else ("k3_s3000_random",))
    for view in ([], ["--json"], ["--runs"], ["--run", "k2_s2000_random"]):
        assert main(["inspect", str(path), *view]) == 2
        one_error(capsys, *names)
    assert main(["plot", str(path), "-o", str(tmp_path / "fig.png")]) == 2
    one_error(capsys, *names)
    assert not (tmp_path / "fig.png").exists()
    assert main(["merge", str(path), "-o", str(tmp_path / "all.h5")]) == 2
    one_error(capsys, *names)
    assert not (tmp_path / "all.h5").exists()


def test_a_resume_drops_a_damaged_run_and_runs_it_again(scene, tmp_path, synthetic_starts, capsys, caplog):
    """A run group under its final name that does not read back (e.g. from a disk that
    filled up before the reservation existed) is dropped by the resume and run again; the
    rerun ends with a complete file and a /selection (was: skipped, then KeyError)."""
    path = tmp_path / "r.h5"
    assert main(["run", str(scene.path), "-o", str(path), "-q"]) == 0
    with h5py.File(path, "r+") as f:
        del f["runs/k3_s3000_lloyd/poses"]
        del f["selection"]
    assert main(["run", str(scene.path), "-o", str(path)]) == 0
    assert "dropping run k3_s3000_lloyd (no dataset 'poses'); it runs again" in caplog.text
    assert "5 runs already stored, 1 to do" in capsys.readouterr().err
    with read_store(path) as f:
        assert len(finished_ids(f)) == 6 and f["selection"].attrs["runs_total"] == 6
        assert read_run(f, "k3_s3000_lloyd").poses == ("rest", "a", "b")


# ---------------------------------------------------------------- schema versions
def as_schema_1(path) -> None:
    """Turn a results file into one of schema 1 (before the finer-mesh check)."""
    with h5py.File(path, "r+") as f:
        f.attrs["schema_version"] = 1
        for g in f["runs"].values():
            del g["finer_capacitance_pF"]
            for name in ("error_estimate", "finer_metric_pF", "error_estimate_wall_s", "bound_mm",
                         "initial_bound_mm"):
                del g.attrs[name]


def test_merge_converts_schema_1_explicitly(scene, tmp_path, capsys, caplog):
    """A schema-1 input is converted, not relabelled: its runs get the schema-2 items of a
    run without the check (0 rows, NaN), the merge says so, and ``inspect --runs`` and
    ``plot`` read the output (they crashed on the relabelled runs)."""
    old, new = tmp_path / "old.h5", tmp_path / "new.h5"
    stored(old, scene)
    as_schema_1(old)
    stored(new, scene, runs=((2, 2001),))
    out = tmp_path / "all.h5"
    assert main(["merge", str(old), str(new), "-o", str(out)]) == 0
    assert "2 runs of schema 1 converted to schema 2" in caplog.text
    with read_store(out) as f:
        assert int(f.attrs["schema_version"]) == 2
        g = f["runs/k3_s3000_random"]
        assert g["finer_capacitance_pF"].shape == (0, 3) and math.isnan(g.attrs["error_estimate"])
        np.testing.assert_array_equal(read_run(f, "k3_s3000_random").final_capacitance_pF,
                                      synthetic_record(3, 3000).final_capacitance_pF)
    capsys.readouterr()
    assert main(["inspect", str(out), "--runs"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 4
    assert main(["plot", str(out), "-o", str(tmp_path / "fig.png")]) == 0
    with pytest.raises(StoreError, match="schema_version 1"):  # the old file itself is not written to
        open_store(old, load_scene(scene.path))


def test_names_from_a_file_are_shown_not_executed(scene, tmp_path, capsys):
    """A scene name holding a terminal's clear-screen sequence, a C1 CSI and a right-to-left
    override is printed as escapes by ``inspect`` (issue 48): every line the commands print
    passes mscap.outputs.printable."""
    path = tmp_path / "r.h5"
    stored(path, scene)
    with h5py.File(path, "r+") as f:
        f.attrs["scene_name"] = "evil\x1b[2J\x9b31m\u202efdp.exe\rX"
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "evil\\x1b[2J\\x9b31m\\u202efdp.exe\\x0dX" in out
    assert not any(c in out for c in "\x1b\x9b\u202e\r")
