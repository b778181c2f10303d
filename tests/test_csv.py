"""The CSV of a run and ``mechdsl plot`` of it: every number the shortest text that reads
back to the same double (as ``repr`` writes it); the units in a comment line under the
header that numpy's readers skip; ``plot`` labelling the axes as the run's plot does; and
anything else than such a CSV a clean located error, without a warning and without echoing
the file."""

from __future__ import annotations

import csv
import io
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import EXAMPLES, ROOT
from mechdsl.cli import main
from mechdsl.outputs.csv import read_csv, write_csv
from mechdsl.results import Results

SLIDER = str(EXAMPLES / "slider_crank.mech")
UNITS = "# units: t [s], slider.x [m], slider.vx [m/s], slider.ax [m/s^2]"
LABELS = (["slider.x [m]", "slider.vx [m/s]", "slider.ax [m/s^2]"], "t [s]")


def fields(text: str) -> list[list[str]]:
    """The rows of a CSV as text, its header and comment lines left out."""
    return [r for r in csv.reader(io.StringIO(text)) if not r[0].startswith("#")][1:]


def bits(a) -> np.ndarray:
    """The bit patterns of doubles (every NaN as the one NaN repr writes and float() reads)."""
    a = np.array(a, dtype=float)
    return np.where(np.isnan(a), np.float64("nan"), a).view(np.uint64)


# -- numbers ----------------------------------------------------------------------------------

def test_the_time_column_of_step_0_1_is_written_as_repr_writes_it(capsys):
    assert main(["run", SLIDER, "--step", "0.1", "-o", "-"]) == 0
    out = capsys.readouterr().out
    t = [row[0] for row in fields(out)]
    assert t == ["0.0", "0.1", "0.2", "0.30000000000000004", "0.4", "0.5", "0.6000000000000001",
                 "0.7000000000000001", "0.8", "0.9", "1.0"]
    assert t == [repr(k * 0.1) for k in range(11)]
    # every number of the file, not only the times
    assert all(repr(float(x)) == x for row in fields(out) for x in row)


SPECIAL = [0.0, -0.0, 0.1, 0.1 + 0.2, 1 / 3, 2.0, 1e-5, 1e16, 1e22, 123456789.125, 5e-324,
           2.2250738585072014e-308, 1.7976931348623157e308, np.nan, np.inf, -np.inf]


@pytest.mark.parametrize("chunk", [1, 5, 2**16])
def test_every_double_is_its_repr_and_reads_back_bit_for_bit(tmp_path, monkeypatch, chunk):
    import mechdsl.outputs.csv

    monkeypatch.setattr(mechdsl.outputs.csv, "CHUNK_VALUES", chunk)
    rng = np.random.default_rng(7)
    k = 400
    raw = rng.integers(0, 2**64, size=(2, 2, k), dtype=np.uint64).view(np.float64)  # any bits
    raw[:, 0, :len(SPECIAL)] = SPECIAL
    raw[1, :, 300:] = np.nan  # the second variant solved 300 instants
    res = Results(times=np.cumsum(np.full(k, 0.1)) - 0.1,
                  data={"a.x": raw[:, 0], "a.vx": raw[:, 1]},
                  sweep={"l": np.array([0.1 + 0.2, -1 / 3])}, n_solved=np.array([k, 300]),
                  status="ok", messages=(), solve_time=0.0, residual=0.0, source_name="m.mech")
    out = tmp_path / "out.csv"
    write_csv(res, out)
    text = out.read_text()
    assert text.startswith("l,t,a.x,a.vx\n0.30000000000000004,0.0,0.0,")
    header, table = res.table()
    written = fields(text)
    assert len(written) == len(table) == k + 300
    # the text of each number is what repr gives: nan, inf and -inf as %.17g wrote them
    assert written == [[repr(x) for x in row] for row in table.tolist()]
    assert written[:len(SPECIAL)] == [
        [repr(0.1 + 0.2), repr(t), repr(x), repr(v)]
        for t, x, v in zip(res.times.tolist(), SPECIAL, raw[0, 1, :len(SPECIAL)].tolist())]
    assert {"nan", "inf", "-inf", "-0.0", "5e-324", "1e+22"} <= {x for r in written for x in r}
    # read back: float(text) is the value, bit for bit (-0.0 and subnormals included)
    assert np.array_equal(bits([[float(x) for x in r] for r in written]), bits(table))
    back = read_csv(str(out))
    assert np.array_equal(bits(back.times), bits(res.times))
    assert np.array_equal(bits(back.sweep["l"]), bits(res.sweep["l"]))
    assert list(back.n_solved) == [k, 300]
    for label in res.data:
        assert np.array_equal(bits(back.data[label]), bits(res.data[label]))


# -- units ------------------------------------------------------------------------------------

def test_the_units_line_follows_the_header_and_numpy_skips_it(tmp_path):
    out = tmp_path / "out.csv"
    assert main(["run", SLIDER, "--sweep", "l=3.5,3", "--t1", "0.01", "-q", "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    # the columns keep their names: whoever selects a column by name finds it
    assert lines[0] == "l,t,slider.x,slider.vx,slider.ax"
    assert lines[1] == "# units: l, t [s], slider.x [m], slider.vx [m/s], slider.ax [m/s^2]"
    rows = np.array(fields(out.read_text()), dtype=float)
    assert rows.shape == (22, 5)
    # numpy's readers skip the comment line: the call that read the CSV before still does
    assert np.array_equal(np.loadtxt(out, delimiter=",", skiprows=1), rows)
    table = np.genfromtxt(out, delimiter=",", names=True)
    assert table.dtype.names[:2] == ("l", "t") and np.array_equal(table["t"], rows[:, 1])
    back = read_csv(str(out))
    assert back.units == {"slider.x": "m", "slider.vx": "m/s", "slider.ax": "m/s^2"}
    assert back.time_unit == "s" and list(back.sweep["l"]) == [3.5, 3.0]


def test_results_without_units_write_no_units_line(tmp_path):
    res = Results(times=np.array([0.0, 0.5]), data={"a.x": np.array([[1.0, 2.0]])}, sweep={},
                  n_solved=np.array([2]), status="ok", messages=(), solve_time=0.0,
                  residual=0.0, source_name="m.mech")
    write_csv(res, tmp_path / "out.csv")
    assert (tmp_path / "out.csv").read_text() == "t,a.x\n0.0,1.0\n0.5,2.0\n"


def test_any_unit_stays_on_one_line_and_reads_back(tmp_path):
    units = {"a.x": "µm, [x]\\y #", "a.vx": "a\rb\u2028c\td\x85e", "a.ax": ""}
    res = Results(times=np.array([0.0, 0.5]), data={k: np.array([[1.0, 2.0]]) for k in units},
                  sweep={}, n_solved=np.array([2]), status="ok", messages=(), solve_time=0.0,
                  residual=0.0, source_name="m.mech", units=units, time_unit="s, or 1/Hz")
    out = tmp_path / "out.csv"
    write_csv(res, out)
    text = out.read_text(encoding="utf-8")
    assert text.split("\n")[1] == ("# units: t [s\\x2c or 1/Hz], a.x [µm\\x2c [x]\\x5cy #], "
                                   "a.vx [a\\x0db\\u2028c\\x09d\\x85e], a.ax")
    assert len(text.splitlines()) == 4  # no line break but the four line ends
    assert np.array_equal(np.loadtxt(out, delimiter=",", skiprows=1), [[0, 1, 1, 1],
                                                                        [0.5, 2, 2, 2]])
    back = read_csv(str(out))
    assert back.units == {"a.x": units["a.x"], "a.vx": units["a.vx"]}
    assert back.time_unit == "s, or 1/Hz"


# -- mechdsl plot -----------------------------------------------------------------------------

@pytest.fixture
def figures(monkeypatch):
    """The matplotlib Figures saved, in order (each still saved to its file)."""
    from matplotlib.figure import Figure

    saved = []
    savefig = Figure.savefig

    def recording(self, *args, **kwargs):
        saved.append(self)
        return savefig(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", recording)
    return saved


def labels(fig) -> tuple[list[str], str]:
    """The y labels of the panels shown and the x label of the time axis."""
    shown = [ax for ax in fig.axes if ax.get_visible()]
    xlabels = {ax.get_xlabel() for ax in shown} - {""}
    assert len(xlabels) == 1
    return [ax.get_ylabel() for ax in shown], xlabels.pop()


def test_plot_of_the_csv_labels_the_axes_as_the_run_s_plot(tmp_path, figures):
    out = tmp_path / "out.csv"
    assert main(["run", SLIDER, "--t1", "0.05", "-q", "-o", str(out),
                 "--plot", str(tmp_path / "run.png")]) == 0
    assert main(["plot", str(out)]) == 0
    assert (tmp_path / "out.png").stat().st_size > 0
    assert len(figures) == 2
    assert labels(figures[0]) == labels(figures[1]) == LABELS
    assert main(["plot", str(out), "--only", "slider.ax,slider.x", "-o",
                 str(tmp_path / "two.svg")]) == 0
    assert labels(figures[2]) == (["slider.ax [m/s^2]", "slider.x [m]"], "t [s]")


@pytest.mark.parametrize("text", [
    "t,slider.x\n0,1.5\n0.5,2\n",  # made by hand
    # as mechdsl wrote it before the units: 17 significant digits
    "t,slider.x\n0,1.5\n0.10000000000000001,2\n0.20000000000000001,2.5\n",
    # a spreadsheet's byte-order mark and line ends, blank lines and comments
    "\ufeff# exported\r\n\r\nt , slider.x\r\n0,1.5\r\n\r\n# a note\r\n0.5,2\r\n",
])
def test_a_csv_without_units_still_plots(tmp_path, figures, text):
    (tmp_path / "old.csv").write_text(text, encoding="utf-8", newline="")
    assert main(["plot", str(tmp_path / "old.csv")]) == 0
    assert labels(figures[0]) == (["slider.x"], "t")


def test_a_units_line_above_the_header_is_read_too(tmp_path, figures):
    (tmp_path / "m.csv").write_text("# units: t [ms], a.phi [rad]\nt,a.phi\n0,1\n1,2\n")
    assert main(["plot", str(tmp_path / "m.csv")]) == 0
    assert labels(figures[0]) == (["a.phi [rad]"], "t [ms]")


SECRET = "hunter2-the-password-of-the-admin"

JUNK = [
    ("binary", b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR" + SECRET.encode(),
     ":1:1: error: not a CSV: the bytes here are not UTF-8 text"),
    ("a NUL", b"t,x\n0,1\n\0" + SECRET.encode(), ":3:1: error: not a CSV: a NUL character "
     "(binary data)"),
    ("empty", b"", ": error: no header: the file is empty (a CSV written by mechdsl run starts "
     "with a line naming its columns, 't' among them)"),
    ("comments", b"\n# " + SECRET.encode() + b"\n\n", ": error: no header: nothing but blank "
     "lines and comments (a CSV written by mechdsl run starts with a line naming its "
     "columns, 't' among them)"),
    ("header only", b"t,slider.x\n", ": error: no rows under the header (the run that wrote it "
     "solved no instant)"),
    ("no t", f"{SECRET},x\n0,1\n".encode(), ":1:1: error: the header names no column 't' (a CSV "
     "written by mechdsl run names the swept params, then 't', then the outputs)"),
    ("a column without a name", b"t,,x\n", ":1:3: error: column 2 of the header has no name"),
    ("a name twice", b"t,x,x\n", ":1:5: error: column 3 of the header is named 'x' as column 2 "
     "is"),
    ("a row too short", b"t,x\n0,1\n1\n", ":3:2: error: 1 value where the header names 2 "
     "columns"),
    ("a row too long", b"t,x\n0,1,2\n", ":2:5: error: 3 values where the header names 2 columns"),
    ("text for a number", f"t,x\n0,1\n1,{SECRET}\n".encode(), ":3:3: error: 'hunter2-the-...' "
     "is not a number in column 2 ('x')"),
    ("no number", b"t,x\n0,1\n1,\n", ":3:3: error: no number in column 2 ('x')"),
    ("a unit of no column", f"t,x\n# units: t [s], {SECRET} [m]\n0,1\n".encode(),
     ":2:17: error: the units line names 'hunter2-the-...', which is no column of the header"),
    ("an unclosed unit", b"t,x\n# units: t [s, x [m]\n0,1\n",
     ":2:10: error: the unit of 't' has no closing ']'"),
]


@pytest.mark.parametrize("content, message", [j[1:] for j in JUNK], ids=[j[0] for j in JUNK])
def test_junk_is_a_clean_located_error_without_a_warning(tmp_path, capsys, recwarn, content,
                                                        message):
    junk = tmp_path / "junk.csv"
    junk.write_bytes(content)
    assert main(["plot", str(junk)]) == 1
    out, err = capsys.readouterr()
    assert (out, err) == ("", f"{junk}{message}\n")
    assert not recwarn.list
    assert SECRET[:13] not in err  # a few characters of the file at most
    assert not (tmp_path / "junk.png").exists()


def test_plot_of_junk_prints_the_error_alone(tmp_path):
    """As a user runs it: no numpy warning, no path inside mechdsl, only the error."""
    (tmp_path / "junk.csv").write_text("t,slider.x\n")
    r = subprocess.run([sys.executable, "-m", "mechdsl", "plot", "junk.csv"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 1
    assert r.stderr == ("junk.csv: error: no rows under the header (the run that wrote it "
                        "solved no instant)\n")


def test_plot_reads_only_a_regular_file(tmp_path):
    os.mkfifo(tmp_path / "pipe.csv")  # open() would wait for a writer for ever
    r = subprocess.run([sys.executable, "-m", "mechdsl", "plot", "pipe.csv"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 1
    assert r.stderr == ("mechdsl: error: cannot read pipe.csv: it is a FIFO (named pipe), not "
                        "a regular file\n")


def test_plot_reads_a_bounded_size(tmp_path, monkeypatch, capsys):
    import mechdsl.reading

    monkeypatch.setattr(mechdsl.reading, "MAX_DATA_BYTES", 100)
    (tmp_path / "big.csv").write_text("t,x\n" + "0.5,1.5\n" * 30)
    assert main(["plot", str(tmp_path / "big.csv")]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"mechdsl: error: cannot read {tmp_path / 'big.csv'}: it has 244 ")
    assert "(mechdsl.reading.MAX_DATA_BYTES)" in err
