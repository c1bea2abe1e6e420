"""``mscap readout`` checks its arguments before any work (issue 21): ``--c-on nan`` or
``--c-off inf`` gave all-NaN results with exit 0, and ``--patterns 100000000`` ran
without bound."""

from __future__ import annotations

import signal

import pytest

from mscap.cli import main
from mscap.errors import ReadoutError
from mscap.readout.array import grid_array
from mscap.readout.patterns import MAX_OPTIMISED_PATTERNS
from mscap.readout.report import choose_patterns


@pytest.mark.parametrize("option, value, words", [
    ("--c-on", "nan", "C_ON (--c-on) must be a finite capacitance >= 0 pF, got nan"),
    ("--c-off", "inf", "C_OFF (--c-off) must be a finite capacitance >= 0 pF, got inf"),
    ("--c-off", "-12", "got -12.0"),
    ("--runs", "-5", "runs must be in 1..1000000, got -5"),
    ("--noise-additive-pF", "nan", "additive noise must be finite"),
])
def test_bad_options_stop_before_reading_the_design(small_scene_dict, write_scene, tmp_path, capsys, option,
                                                    value, words):
    # The design file does not exist: the option is what the one line must be about.
    scene = write_scene(small_scene_dict)
    assert main(["readout", str(scene), "--design", str(tmp_path / "missing.h5"), option, value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err


def _timeout(signum, frame):
    raise TimeoutError("optimise_patterns ran on")


@pytest.mark.parametrize("spec", [str(MAX_OPTIMISED_PATTERNS + 1), "100000000", "²"])
def test_pattern_counts_are_bounded(spec):
    array = grid_array(4)
    signal.signal(signal.SIGALRM, _timeout)
    signal.alarm(10)
    try:
        with pytest.raises(ReadoutError, match=r"--patterns|at most 4096"):
            choose_patterns(array, spec)
    finally:
        signal.alarm(0)


def test_rows_beyond_k_are_refused():
    # 10**9 rows of 4 capacitors: a billion empty leads the pattern search would draw.
    with pytest.raises(ReadoutError, match=r"rows and columns must be <= k = 4"):
        grid_array(4, rows=10**9)


def test_a_routed_wiring_is_read_and_a_bad_one_is_one_line(tmp_path):
    import json

    from mscap.readout.array import read_wiring

    wiring = {"array": {"rows": 2, "columns": 2, "slots": [{"capacitor": 0, "row": 1, "column": 0},
                                                           {"capacitor": 1, "row": 0, "column": 0},
                                                           {"capacitor": 2, "row": 0, "column": 1}]}}
    path = tmp_path / "fabrication.json"
    path.write_text(json.dumps(wiring))
    array = read_wiring(path, 3)
    assert (array.rows, array.columns, array.slots) == (2, 2, ((1, 0), (0, 0), (0, 1)))
    with pytest.raises(ReadoutError, match=r"wires capacitors \[0, 1, 2\], the design has 2"):
        read_wiring(path, 2)
    wiring["array"]["rows"] = 10**12
    path.write_text(json.dumps(wiring))
    with pytest.raises(ReadoutError, match="whole numbers in 0..100"):
        read_wiring(path, 3)
    path.write_text("{not json")
    with pytest.raises(ReadoutError, match="not an `mscap fabricate` fabrication.json"):
        read_wiring(path, 3)
    wiring["array"]["rows"] = 1  # slot row 1 of a 1-row array
    path.write_text(json.dumps(wiring))
    with pytest.raises(ReadoutError, match=r"capacitor 0 in slot \[1,0\] outside the 1 x 2 array"):
        read_wiring(path, 3)
