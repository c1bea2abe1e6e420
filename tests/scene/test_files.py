"""Scene files are read only when they are regular files, and at most MAX_SCENE_BYTES of
them (issue 48): a FIFO would block the open, a device never end, a directory or a socket
give an OS error deep inside the read. Each is one SceneError naming the file, at once."""

from __future__ import annotations

import os
import socket

import pytest

from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.settings import MAX_SCENE_BYTES
from tests.conftest import within


def special(tmp_path, kind: str) -> str:
    path = tmp_path / f"{kind}.toml"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "directory":
        path.mkdir()
    elif kind == "socket":
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(path))
        special.keep = server  # bound for the test's length
    elif kind == "huge":
        with open(path, "wb") as f:
            f.truncate(MAX_SCENE_BYTES + 1)  # sparse: nothing written
    elif kind == "device":
        return "/dev/zero"
    return str(path)


@pytest.mark.parametrize("kind, said", [("fifo", "is a FIFO, not a scene file"),
                                        ("device", "is a character device, not a scene file"),
                                        ("directory", "is a directory, not a scene file"),
                                        ("socket", "cannot read scene file"),
                                        ("huge", f"{MAX_SCENE_BYTES + 1} bytes is not a scene file")])
def test_only_a_regular_file_is_read_as_a_scene(tmp_path, kind, said):
    path = special(tmp_path, kind)
    with within(10), pytest.raises(SceneError, match=said) as error:
        load_scene(path)
    assert str(error.value).startswith(path) and "\n" not in str(error.value)
