"""Every file argument of every subcommand against what is not a file mscap reads or
writes (issue 48): a FIFO (an ``open`` waits for a writer for ever), a character device
(``/dev/zero`` never ends), a directory, a socket and a 1 GB file, as the file itself and
as the files inside a directory argument (``outlines.json``, ``fabrication.json``, the
stencils). Each is one ``mscap: error:`` line naming it, status 2, never a hang, a
traceback or a read of the gigabyte; only ``plot -o`` replaces what it finds (a link, a
regular file), as every output writer does (mscap.outputs.replace_file)."""

from __future__ import annotations

import copy
import os
import socket

import pytest

from mscap.cli import main
from mscap.scene import load_scene
from mscap.service.store import open_store, write_run
from tests.calibration.test_calibration import calibration_scene
from tests.conftest import SMALL_SCENE, synthetic_record, to_toml, within

KINDS = ("fifo", "device", "directory", "socket", "gigabyte")
INSIDE = ("x", "outlines.json", "summary.json", "fabrication.json", "bottom.dxf", "top.dxf")

#: argv templates: X the special file, DIR a directory whose files are all special, OUT a
#: fresh directory; S and C a plain and a calibration scene, R and RC their results files.
TEMPLATES = {
    "mesh SCENE": "mesh X",
    "inspect RESULTS": "inspect X",
    "plot RESULTS": "plot X -o OUT/f.png",
    "merge RESULTS": "merge X -o OUT/m.h5",
    "fabricate RESULTS": "fabricate X -o OUT/fab",
    "fabricate OPTIMIZE_DIR": "fabricate DIR -o OUT/fab",
    "readout --design": "readout S --design X",
    "readout --wiring": "readout S --design R --wiring X",
    "simulate --wiring": "simulate S --wiring DIR",
    "calibrate --design FILE": "calibrate C --design X -o OUT/cal --cache OUT/c.h5",
    "calibrate --design DIR": "calibrate C --design DIR -o OUT/cal --cache OUT/c.h5",
    "calibrate --wiring": "calibrate C --design RC --wiring DIR -o OUT/cal --cache OUT/c.h5",
    "calibrate --cache": "calibrate C --design RC --cache X -o OUT/cal",
    "run -o": "run S -o X",
    "merge -o": "merge R -o X",
    "plot -o": "plot R -o X",
}


@pytest.fixture(scope="module")
def place(tmp_path_factory):
    root = tmp_path_factory.mktemp("special")
    (root / "s.toml").write_text(to_toml(copy.deepcopy(SMALL_SCENE)))
    (root / "c.toml").write_text(to_toml(calibration_scene()))
    for scene, out in (("s.toml", "r.h5"), ("c.toml", "rc.h5")):
        with open_store(root / out, load_scene(root / scene)) as store:
            write_run(store, synthetic_record(2, 2000))
    sockets = []
    for kind in KINDS:
        (root / kind).mkdir()
        for name in INSIDE:
            path = root / kind / name
            if kind == "fifo":
                os.mkfifo(path)
            elif kind == "device":
                path.symlink_to("/dev/zero")
            elif kind == "directory":
                path.mkdir()
            elif kind == "socket":
                sockets.append(socket.socket(socket.AF_UNIX))
                sockets[-1].bind(str(path))
            else:
                with open(path, "wb") as f:
                    f.truncate(2**30)  # sparse: nothing written
    yield root
    for s in sockets:
        s.close()


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("argument", sorted(TEMPLATES))
def test_a_special_file_is_one_line_at_once(place, tmp_path, capsys, argument, kind):
    special, directory = place / kind / "x", place / kind
    words = {"X": str(special), "DIR": str(directory), "OUT": str(tmp_path), "S": str(place / "s.toml"),
             "C": str(place / "c.toml"), "R": str(place / "r.h5"), "RC": str(place / "rc.h5")}
    argv = [words.get(a, a) for a in TEMPLATES[argument].split()]
    argv = [a.replace("OUT/", f"{tmp_path}/") for a in argv]
    with within(20):  # a hang fails this test, not the suite
        status = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err, err[-2000:]
    if argument == "plot -o" and kind in ("device", "gigabyte"):  # a link, a regular file: replaced
        assert status == 0 and special.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        special.unlink()
        special.symlink_to("/dev/zero") if kind == "device" else open(special, "wb").truncate(2**30)
        return
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2 and len(lines) == 1 and lines[0].startswith("mscap: error: "), (argv, err)
    assert str(directory) in lines[0], (argv, lines[0])
    assert os.path.lexists(special) and (kind != "fifo" or special.is_fifo())  # nothing removed or replaced


def test_a_figure_name_without_a_suffix_is_a_png_there_and_a_wrong_suffix_is_refused(place, tmp_path, capsys):
    """matplotlib adds ``.png`` to a name without a suffix: the figure went to the hidden
    temporary's name and an empty file to the one asked for."""
    assert main(["plot", str(place / "r.h5"), "-o", str(tmp_path / "figure")]) == 0
    assert (tmp_path / "figure").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure"]
    capsys.readouterr()
    assert main(["plot", str(place / "r.h5"), "-o", str(tmp_path / "figure.h5")]) == 2
    assert "a figure is one of .png, .pdf, .svg" in capsys.readouterr().err
    assert not (tmp_path / "figure.h5").exists()
