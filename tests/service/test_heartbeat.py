"""The master's heartbeat (mscap/service/heartbeat.py): bounded silence, every busy worker named."""

from __future__ import annotations

from mscap.service.heartbeat import Heartbeat, Progress
from mscap.service.selection import StartConfig


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_lines_only_after_the_interval_of_silence_and_name_every_busy_worker():
    clock, lines = Clock(), []
    hb = Heartbeat(lines.append, interval=20, clock=clock)
    a, b = StartConfig(4, 4000, "lloyd"), StartConfig(3, 3001, "random")
    busy = {2: (b, 95.0), 1: (a, 90.0)}
    clock.t = 119.9
    hb.tick(busy)
    assert lines == []                                   # 19.9 s of silence: nothing yet
    hb.update(Progress(a.id, 4, 7, 0.51234, -0.5))
    clock.t = 120.0
    hb.tick(busy)
    assert lines == ["... rank 1 k4_s4000_lloyd: step 7, 0.5123 pF, 30 s; "
                     "rank 2 k3_s3001_random: setting up, 25 s"]
    clock.t = 130.0
    hb.tick(busy)
    assert len(lines) == 1                               # at most one line per interval
    hb.say("[1/4] k4_s4000_lloyd: ok")                   # a progress line restarts the silence
    clock.t = 145.0
    hb.tick(busy)
    assert len(lines) == 2
    clock.t = 150.0
    hb.tick(busy)
    assert len(lines) == 3 and lines[-1].startswith("... rank 1")


def test_progress_says_what_the_start_optimises():
    """The read-back bound (mm) for a scene designed for it, the min L1 (pF) for the
    paper's objective, J with the min L1 beside it for family poses in noise units."""
    assert Progress("r", 3, 5, 0.51234, 0.3125, kind="bound").objective == "bound 0.312 mm"
    assert Progress("r", 3, 5, 0.51234, -0.51234).objective == "0.5123 pF"
    assert Progress("r", 3, 5, 0.51234, -2.5, kind="J").objective == "J -2.5 (min L1 0.5123 pF)"


def test_no_line_when_idle_quiet_or_disabled():
    clock, lines = Clock(), []
    busy = {1: (StartConfig(2, 2000, "lloyd"), 0.0)}
    clock.t = 1000.0
    Heartbeat(lines.append, interval=20, clock=clock).tick({})          # nothing running
    Heartbeat(lines.append, interval=0, clock=clock).tick(busy)         # --heartbeat 0
    Heartbeat(None, interval=20, clock=clock).tick(busy)                # --quiet
    assert lines == []
