"""Outputs are never half-written: an interrupted run keeps the instants solved so far in a
complete file, and says so."""

import csv
import signal

import numpy as np

from closed_forms import slider_crank
from conftest import EXAMPLES
from test_outputs_safety import finish, start_solving


def test_ctrl_c_keeps_the_instants_solved_so_far(tmp_path):
    out = tmp_path / "out.csv"
    # the signal comes once the run is solving (its progress bar is drawn), not after a delay
    proc, reader = start_solving([EXAMPLES / "slider_crank.mech", "--t1", "2000", "--step",
                                  "0.001", "-o", out])
    proc.send_signal(signal.SIGINT)
    stderr = finish(proc, reader)
    assert proc.returncode == 130, stderr
    text = out.read_text()
    assert text.endswith("\n")
    rows = list(csv.reader(text.splitlines()))
    assert rows[0] == ["t", "slider.x", "slider.vx", "slider.ax"]
    assert rows.pop(1)[0] == "# units: t [s]"  # the units line under the header
    data = np.array(rows[1:], dtype=float)
    solved = len(data)
    assert 0 < solved < 2_000_001
    assert f"interrupted; the {solved} instants solved so far are in {out}" in stderr
    assert "Traceback" not in stderr
    np.testing.assert_allclose(data[:, 0], 0.001 * np.arange(solved), atol=1e-9)
    x, _, _ = slider_crank(2.0, 3.5, np.pi / 4 + 4 * np.pi * data[:, 0], 0, 0)
    np.testing.assert_allclose(data[:, 1], x, atol=1e-12)
