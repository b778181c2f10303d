"""A model file is data: opening it must be as safe as opening a CSV.

Hostile and unlucky input to the language front end and to the files a model reads: the
parser's cache, devices, FIFOs and other people's files named as tables or meshes, a corrupt
mesh, expressions thousands of levels deep, lines of millions of characters, huge files, a
byte-order mark and old Mac line ends. Each test asserts the behaviour (status, message,
location, files) against what the input says, not against earlier output of the program.
"""

import os
import pickle
import stat
import subprocess
import sys
import tempfile

import numpy as np
import pytest

import mechdsl
import mechdsl.grammar.cache as grammar_cache
import mechdsl.grammar.parser as parse_module
import mechdsl.reading as reading
from conftest import EXAMPLES, ROOT
from mechdsl.grammar import expr as E
from mechdsl.cli import main
from mechdsl.grammar.derive import derivative
from mechdsl.errors import MechError, format_error
from mechdsl.grammar.parser import MAX_DEPTH, parse, parse_expr

# A crank of length r pinned at its end A to the ground's origin: its centre is at
# x = (r/2) cos(phi), y = (r/2) sin(phi), whatever drives phi.
CRANK = """param r = {r}
body crank {{ guess = (1, 0, 0)  point A = (-r/2, 0) }}
joint A: revolute(ground.origin, crank.A)
drive d: angle(crank) = {f}
simulate t = 0 .. 1 step 0.05
output crank.x, crank.y, crank.phi, crank.omega, crank.alpha
"""


def crank(r="2", f="t"):
    return CRANK.format(r=r, f=f)


def where(err: MechError) -> tuple[int, int]:
    return err.span.line, err.span.column


def column_of(text: str, token: str) -> tuple[int, int]:
    """(line, column) of the first ``token`` in ``text``, counted as an editor does."""
    i = text.index(token)
    return text.count("\n", 0, i) + 1, i - (text.rfind("\n", 0, i) + 1) + 1


def run_cli(*args, cwd=ROOT):
    # for what must not hang even when broken (a FIFO): the timeout is a guard, not a test
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120)


# ---------------------------------------------------------------------------------------------
# 1. The parser's cache: never lark's pickle in the shared temporary folder


@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    """A fresh per-user cache folder, and a shared temporary folder watched for writes."""
    shared = tmp_path / "shared-tmp"
    shared.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(shared))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return tmp_path / "cache" / "mechdsl", shared


def test_the_parser_leaves_nothing_in_the_shared_temporary_folder(private_cache, monkeypatch):
    # lark's cache=True writes a pickle to tempfile.gettempdir() on the first build and
    # unpickles it on the next: neither may happen
    cache_dir, shared = private_cache
    loads = []
    monkeypatch.setattr(pickle, "load", lambda *a, **k: loads.append(a) or {})
    monkeypatch.setattr(pickle, "loads", lambda *a, **k: loads.append(a) or {})
    for _ in range(2):  # builds and stores, then loads from the private cache
        parser = parse_module._build_parser()
        assert parser.parse("param a = 1", start="start").children[0].data == "param"
    assert list(shared.iterdir()) == [] and loads == []
    assert [p.suffix for p in cache_dir.iterdir()] == [".json"]


def test_the_private_cache_is_owner_only(private_cache):
    cache_dir, _ = private_cache
    parse_module._build_parser()
    assert stat.S_IMODE(cache_dir.stat().st_mode) == 0o700
    (entry,) = cache_dir.iterdir()
    assert stat.S_IMODE(entry.stat().st_mode) == 0o600


class _Planted:
    """Unpickling this creates the folder ``marker``: the proof that code ran."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return os.mkdir, (self.marker,)


def test_a_pickle_planted_in_the_cache_runs_no_code(private_cache, tmp_path):
    cache_dir, _ = private_cache
    parse_module._build_parser()
    marker = tmp_path / "code-ran"
    for entry in cache_dir.iterdir():  # the cache file, replaced by a malicious pickle
        entry.write_bytes(pickle.dumps(_Planted(str(marker))))
    parser = parse_module._build_parser()
    assert not marker.exists()
    assert parser.parse("param a = 1", start="start").children[0].data == "param"


def test_a_cache_folder_others_may_write_is_not_used(private_cache):
    cache_dir, _ = private_cache
    cache_dir.mkdir(parents=True)
    cache_dir.chmod(0o777)
    parse_module._build_parser()
    assert list(cache_dir.iterdir()) == []


def test_a_cache_folder_of_another_user_is_not_used(private_cache, monkeypatch):
    cache_dir, _ = private_cache
    cache_dir.mkdir(parents=True, mode=0o700)
    monkeypatch.setattr(grammar_cache.os, "getuid", lambda: os.stat(cache_dir).st_uid + 1)
    parse_module._build_parser()
    assert list(cache_dir.iterdir()) == []


def test_a_cache_file_others_may_write_is_not_read(private_cache, monkeypatch):
    cache_dir, _ = private_cache
    parse_module._build_parser()
    decoded = []
    real_loads = grammar_cache.json.loads
    monkeypatch.setattr(grammar_cache.json, "loads",
                        lambda *a, **k: decoded.append(1) or real_loads(*a, **k))
    parse_module._build_parser()
    assert decoded == [1]  # a private file is read
    (entry,) = cache_dir.iterdir()
    entry.chmod(0o666)
    decoded.clear()
    assert parse_module._build_parser().parse("param a = 1", start="start")
    assert decoded == []  # one others may write is not


# ---------------------------------------------------------------------------------------------
# 2. Files a model reads: regular files only, sizes checked, content never echoed

TABLE_DRIVE = crank(f='table("{name}", t)')


def table_model(tmp_path, name):
    path = tmp_path / "model.mech"
    text = TABLE_DRIVE.replace("{name}", name)
    path.write_text(text)
    return path, text


def load_error(path, registry) -> MechError:
    with pytest.raises(MechError) as info:
        mechdsl.load(path, registry=registry)
    return info.value


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/null"])
def test_a_device_as_a_table_is_refused_at_once(tmp_path, registry, device):
    path, text = table_model(tmp_path, device)
    err = load_error(path, registry)
    assert err.message == (f"cannot read the table {device}: it is a character device, not a "
                           "regular file")
    assert where(err) == column_of(text, f'"{device}"')


def test_a_folder_as_a_table_is_refused(tmp_path, registry):
    (tmp_path / "data").mkdir()
    path, text = table_model(tmp_path, "data")
    err = load_error(path, registry)
    assert err.message == "cannot read the table data: it is a directory, not a regular file"


def test_a_fifo_as_a_table_or_a_model_does_not_block(tmp_path):
    os.mkfifo(tmp_path / "pipe.csv")
    path, text = table_model(tmp_path, "pipe.csv")
    r = run_cli("check", path)
    line, col = column_of(text, '"pipe.csv"')
    assert r.returncode == 1
    assert r.stderr.startswith(f"{path}:{line}:{col}: error: cannot read the table pipe.csv: "
                               "it is a FIFO (named pipe), not a regular file")
    os.mkfifo(tmp_path / "pipe.mech")
    r = run_cli("check", tmp_path / "pipe.mech")
    assert r.returncode == 1
    assert "it is a FIFO (named pipe), not a regular file" in r.stderr


def test_another_text_file_as_a_table_is_not_echoed(tmp_path, registry):
    (tmp_path / "hosts").write_text("127.0.0.1 localhost secret-host-name\n")
    path, _ = table_model(tmp_path, "hosts")
    err = load_error(path, registry)
    assert err.message == ("hosts:1: expected two numbers (x, y), but '127.0.0.1' is not a "
                           "number")
    assert "localhost" not in format_error(err) and "secret" not in format_error(err)


def test_a_bad_field_is_shown_cut_to_twelve_characters(tmp_path, registry):
    (tmp_path / "data.csv").write_text("0 0\n1 1\n2 password=hunter2-and-more\n")
    path, _ = table_model(tmp_path, "data.csv")
    err = load_error(path, registry)
    assert err.message == ("data.csv:3: expected two numbers (x, y), but 'password=hun...' "
                           "is not a number")


@pytest.mark.parametrize("line, why", [(";;,", "found none"), ("3", "found one"),
                                       ("3 x", "but 'x' is not a number")])
def test_a_line_without_two_numbers_is_named(tmp_path, registry, line, why):
    (tmp_path / "data.csv").write_text(f"0 0\n1 1\n{line}\n")
    path, _ = table_model(tmp_path, "data.csv")
    assert load_error(path, registry).message == f"data.csv:3: expected two numbers (x, y), {why}"


def test_a_table_over_the_size_limit_is_refused_before_reading(tmp_path, registry,
                                                                monkeypatch):
    monkeypatch.setattr(reading, "MAX_DATA_BYTES", 64)
    rows = "".join(f"{k} {k * k}\n" for k in range(20))
    (tmp_path / "data.csv").write_text(rows)
    path, text = table_model(tmp_path, "data.csv")
    err = load_error(path, registry)
    assert err.message == (f"cannot read the table data.csv: it has {len(rows)} bytes, more "
                           "than the limit of 64 bytes (mechdsl.reading.MAX_DATA_BYTES)")
    assert where(err) == column_of(text, '"data.csv"')
    monkeypatch.setattr(reading, "MAX_DATA_BYTES", len(rows))  # exactly at the limit: read
    res = mechdsl.load(path, registry=registry).simulate()
    t = res["t"]
    np.testing.assert_allclose(res["crank.phi"], t * t, atol=1e-12)  # the spline of k^2


def test_a_table_with_a_bom_and_old_mac_line_ends_is_read(tmp_path, registry):
    (tmp_path / "data.csv").write_bytes(
        b"\xef\xbb\xbftime;angle\r" + b"".join(b"%d;%d\r" % (k, 3 * k) for k in range(3)))
    path, _ = table_model(tmp_path, "data.csv")
    res = mechdsl.load(path, registry=registry).simulate()
    np.testing.assert_allclose(res["crank.phi"], 3 * res["t"], atol=1e-12)


SHAPE_MODEL = """body plate {{ shape = "{name}"  point A = (0, 0) }}
joint A: revolute(ground.origin, plate.A)
drive d: angle(plate) = t
simulate t = 0 .. 1 step 0.5
"""


def test_a_corrupt_mesh_prints_nothing_and_exits_nothing(tmp_path, capsys):
    # meshio tries .msh as ANSYS then Gmsh, prints each reader's complaint to standard output
    # (the CSV stream under -o -) and calls sys.exit(1); some readers quote the file
    (tmp_path / "bad.msh").write_text("$MeshFormat\nSECRET-TOKEN 1 2 3\n$Garbage\n")
    text = SHAPE_MODEL.format(name="bad.msh")
    (tmp_path / "m.mech").write_text(text)
    status = main(["run", str(tmp_path / "m.mech"), "-o", "-"])
    out, err = capsys.readouterr()
    line, col = column_of(text, '"bad.msh"')
    assert status == 1 and out == ""
    assert err.splitlines()[0] == (
        f"{tmp_path / 'm.mech'}:{line}:{col}: error: cannot read the shape bad.msh: it is not "
        "a mesh meshio can read as ansys or gmsh (SystemExit)")
    assert "SECRET" not in err


@pytest.mark.parametrize("name, why", [
    ("plate.xdmf", "xdmf files can make meshio read other files"),
    ("plate.inp", "abaqus files can make meshio read other files"),
    ("plate.node", "tetgen files can make meshio read other files"),
    ("plate.vol.gz", "a compressed file can expand without bound"),
    ("plate.txt", "its extension names no mesh format meshio reads"),
])
def test_meshes_that_would_read_other_files_are_refused(tmp_path, name, why):
    (tmp_path / name).write_text("<Xdmf><Domain/></Xdmf>\n")
    (tmp_path / "m.mech").write_text(SHAPE_MODEL.format(name=name))
    with pytest.raises(MechError) as info:
        mechdsl.load(tmp_path / "m.mech")
    assert info.value.message.startswith(f"cannot read the shape {name}: {why}")


def test_a_device_as_a_mesh_is_refused(tmp_path):
    text = SHAPE_MODEL.format(name="/dev/zero")
    (tmp_path / "m.mech").write_text(text)
    with pytest.raises(MechError) as info:
        mechdsl.load(tmp_path / "m.mech")
    assert info.value.message == ("cannot read the shape /dev/zero: it is a character device, "
                                  "not a regular file")
    assert where(info.value) == column_of(text, '"/dev/zero"')


def test_the_model_records_the_real_paths_of_the_files_it_reads(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    (data / "motion.csv").write_text("0 0\n1 1\n")
    (data / "plate.msh").write_bytes((EXAMPLES / "data" / "plate.msh").read_bytes())
    os.symlink(data / "motion.csv", tmp_path / "link.csv")
    (tmp_path / "m.mech").write_text(
        'body plate { shape = "data/plate.msh"  point A = (0, 0) }\n'
        "joint A: revolute(ground.origin, plate.A)\n"
        'drive d: angle(plate) = table("link.csv", t) + table("data/motion.csv", t) '
        '+ table("./data/../link.csv", t)\n')
    model = mechdsl.load(tmp_path / "m.mech").model
    assert model.files == (os.path.realpath(data / "plate.msh"),
                           os.path.realpath(data / "motion.csv"))
    assert parse("param a = 1").files == ()


# ---------------------------------------------------------------------------------------------
# 3. Deep expressions: thousands of terms work; pathological nesting is a located error


def fourier(n):
    """The text of sum_k a_k sin(k t), k = 1..n, and its coefficients."""
    a = [0.1 / (k * k) for k in range(1, n + 1)]
    return " + ".join(f"{c!r}*sin({k}*t)" for k, c in enumerate(a, 1)), np.array(a)


@pytest.mark.parametrize("n", [500, 2000])
def test_a_long_fourier_drive_runs_to_its_closed_form(registry, n):
    text, a = fourier(n)
    mech = mechdsl.loads(crank(f=text), "fourier.mech", registry=registry)
    assert E.to_text(mech.model.drives[0].function) == text
    res = mech.simulate()
    t = res["t"]
    k = np.arange(1, n + 1)[:, None]
    phi = (a[:, None] * np.sin(k * t)).sum(axis=0)
    omega = (a[:, None] * k * np.cos(k * t)).sum(axis=0)
    alpha = -(a[:, None] * k * k * np.sin(k * t)).sum(axis=0)
    np.testing.assert_allclose(res["crank.phi"], phi, rtol=0, atol=1e-13)
    np.testing.assert_allclose(res["crank.omega"], omega, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res["crank.alpha"], alpha, rtol=0, atol=1e-11)
    np.testing.assert_allclose(res["crank.x"], np.cos(phi), rtol=0, atol=1e-13)  # r/2 = 1


def test_a_long_sum_param_evaluates_in_its_order(registry):
    terms = [0.1 * k for k in range(1, 2001)]
    text = "2 + 0" * 1 + "".join(f" + {c!r}" for c in terms)
    mech = mechdsl.loads(crank(r=text), "sum.mech", registry=registry)
    expected = 2.0 + 0.0
    for c in terms:  # left to right, as written: the same floating-point result
        expected += c
    assert E.evaluate(mech.model.params[0].value, {}) == expected
    res = mech.simulate()
    np.testing.assert_allclose(res["crank.x"], expected / 2 * np.cos(res["t"]), rtol=1e-14)


def test_a_long_set_on_the_command_line_runs(tmp_path, capsys):
    (tmp_path / "c.mech").write_text(crank(r="1"))
    status = main(["run", str(tmp_path / "c.mech"), "-o", "-", "--set",
                   "r=" + "+".join(["1"] * 2000)])
    out, err = capsys.readouterr()
    assert status == 0, err
    rows = np.loadtxt(out.splitlines(), delimiter=",", skiprows=1)  # the units line skipped
    np.testing.assert_allclose(rows[:, 1], 1000 * np.cos(rows[:, 0]), rtol=1e-14)


def test_derivatives_of_deep_expressions_are_exact():
    n = 3000
    e = parse_expr(" + ".join(f"{k}*t^2" for k in range(1, n + 1)), "f", ["t"])
    d1, d2 = derivative(e), derivative(derivative(e))
    total = n * (n + 1) // 2
    assert E.evaluate(d1, {"t": 3.0}) == 2 * total * 3.0
    assert E.evaluate(d2, {"t": 3.0}) == 2 * total
    # products nest as deep; their derivatives share subtrees instead of copying them
    p = parse_expr("*".join(["t"] * 3000), "f", ["t"])
    assert E.evaluate(derivative(p), {"t": 1.0}) == 3000.0
    assert E.evaluate(derivative(derivative(p)), {"t": 1.0}) == 3000.0 * 2999.0
    # a max of thousands of arguments: its derivative is that of the largest, here 3000 t
    m = parse_expr("max(" + ", ".join(f"{k}*t" for k in range(1, 3001)) + ")", "f", ["t"])
    assert E.evaluate(derivative(m), {"t": 2.0}) == 3000.0
    assert E.evaluate(derivative(m), {"t": -2.0}) == 1.0
    assert E.evaluate(derivative(derivative(m)), {"t": 2.0}) == 0.0


@pytest.mark.parametrize("text, first", [
    ("1" + "+1" * 100_000, "1"),                       # a flat sum of 10^5 terms
    ("-" * 100_000 + "1", None),                       # unary minus 10^5 deep
    ("sin(" * 30_000 + "t" + ")" * 30_000, None),      # calls 3 times the limit deep
    ("(1+" * 30_000 + "1" + ")" * 30_000, None),       # parenthesised sums
    ("2^" * 30_000 + "2", None),                       # a tower of powers
])
def test_pathological_nesting_is_a_located_error(text, first):
    with pytest.raises(MechError) as info:
        parse(f"param r = {text}\n", "deep.mech")
    err = info.value
    assert err.message == (f"the expression is nested too deeply: {MAX_DEPTH + 1:,} levels "
                           f"here, more than the limit of {MAX_DEPTH:,} (a sum of n terms "
                           "counts n levels; split it with params)")
    assert err.source.name == "deep.mech" and err.span.line == 1
    assert 11 <= err.span.column <= 10 + len(text)
    if first is not None:  # a left-deep sum: where its too-deep part starts, its first term
        assert err.span.column == 11
    formatted = format_error(err)
    assert formatted.startswith(f"deep.mech:1:{err.span.column}: error: ")
    assert len(formatted) < 2000


def test_pathological_nesting_on_the_command_line_is_a_user_error(tmp_path, capsys):
    (tmp_path / "c.mech").write_text(crank(r="1"))
    status = main(["check", str(tmp_path / "c.mech"), "--set", "r=" + "-" * 50_000 + "1"])
    err = capsys.readouterr().err
    assert status == 1
    assert err.startswith("--set r:1:") and f"more than the limit of {MAX_DEPTH:,}" in err


def test_parentheses_alone_do_not_nest_a_value():
    n = 100_000
    model = parse(f"param r = {'(' * n}1.5{')' * n}\n")
    assert E.evaluate(model.params[0].value, {}) == 1.5


def test_a_mistake_deep_in_a_long_expression_is_located():
    text = "param a = 1\nparam b = " + " + ".join(["a"] * 3000) + " + c\n"
    with pytest.raises(MechError) as info:
        parse(text, "m.mech")
    assert info.value.message == "unknown name 'c' in param 'b'"
    assert where(info.value) == column_of(text, "c\n")


def test_deep_text_and_equality_need_no_recursion():
    text = " + ".join(f"sin({k}*t)" for k in range(1, 3001))
    e = parse_expr(text, "f", ["t"])
    assert E.to_text(e) == text
    again = parse_expr(text, "f", ["t"])
    assert E.equal(e, again) and not E.equal(e, parse_expr(text + " + 1", "f", ["t"]))
    # 'if' branches that are equal collapse, however deep
    assert E.cond(E.Name("c"), e, again) is e


# ---------------------------------------------------------------------------------------------
# 4. Sizes of messages


def test_an_error_on_a_ten_million_character_line_prints_a_window():
    n = 10_000_000
    text = "param r = 1" + " " * n + "$ " + "x" * 1000 + "\n"
    with pytest.raises(MechError) as info:
        parse(text, "long.mech")
    formatted = format_error(info.value)
    head, shown, caret = formatted.splitlines()
    col = text.index("$") + 1
    assert head == f"long.mech:1:{col}: error: unexpected character '$'"
    assert len(formatted) < 1000
    assert shown.startswith("    1 | ...") and shown.endswith("...")
    assert caret.index("^") == shown.index("$") and caret.count("^") == 1


def test_a_ten_million_character_name_is_cut_in_the_message():
    name = "a" * 10_000_000
    with pytest.raises(MechError) as info:
        parse(f"param r = {name}\n", "long.mech")
    err = info.value
    assert err.message == f"unknown name '{'a' * 40}...' in param 'r'"
    formatted = format_error(err)
    shown, caret = formatted.splitlines()[1:]
    assert len(formatted) < 1000
    assert shown == "    1 | param r = " + "a" * 90 + "..."
    assert caret == "      | " + " " * 10 + "^" * 90  # cut at the window's end


def test_an_error_at_the_start_of_a_long_line_shows_its_start():
    text = "param r = $" + "1" * 5000
    with pytest.raises(MechError) as info:
        parse(text, "m.mech")
    shown, caret = format_error(info.value).splitlines()[1:]
    assert shown == "    1 | " + text[:100] + "..."
    assert caret == "      | " + " " * 10 + "^"


def test_notes_and_long_messages_are_bounded():
    err = MechError("x" * 100_000, notes=["y" * 100_000] + [f"note {k}" for k in range(50_000)])
    lines = format_error(err).splitlines()
    assert lines[0] == "error: " + "x" * 2000 + "..."
    assert lines[1] == "  note: " + "y" * 1000 + "..."
    assert lines[2:-1] == [f"  note: note {k}" for k in range(19)]
    assert lines[-1] == "  note: and 49981 more notes"


def test_terminal_escapes_in_the_source_are_not_echoed():
    with pytest.raises(MechError) as info:
        parse('units length = "\x1b[2J\x1b]0;pwned\x07", weight = "kg"', "m.mech")
    formatted = format_error(info.value)
    assert "\x1b" not in formatted and "\x07" not in formatted
    assert "units length = \"?[2J?]0;pwned?\", weight" in formatted


def test_a_long_list_of_cell_types_is_bounded():
    from mechdsl.errors import listing

    assert listing(["a", "b", "c"]) == "a, b, c"
    assert listing([str(k) for k in range(6)]) == "0, 1, 2, 3, 4, 5"
    assert listing([str(k) for k in range(100)]) == "0, 1, 2, 3, 4 and 95 more"


# ---------------------------------------------------------------------------------------------
# 5. Big files


def test_a_model_over_the_size_limit_is_refused_at_once(tmp_path, capsys):
    path = tmp_path / "big.mech"
    with open(path, "wb") as f:  # 50 MB of nothing on disk: the size alone must refuse it
        f.truncate(50 * 2**20)
    status = main(["check", str(path)])
    err = capsys.readouterr().err
    assert status == 1
    (line,) = err.splitlines()  # the command line may prefix its name: "mechdsl: error: ..."
    assert line.endswith(f"error: cannot read {path}: it has 52,428,800 bytes (50.0 MiB), more "
                         f"than the limit of {reading.MAX_MODEL_BYTES:,} bytes "
                         f"({reading.MAX_MODEL_BYTES / 2**20:.1f} MiB) "
                         "(mechdsl.reading.MAX_MODEL_BYTES)")


@pytest.mark.parametrize("target", ["/dev/zero", "."])
def test_a_model_that_is_no_file_is_refused(capsys, target):
    assert main(["check", target]) == 1
    kind = "a character device" if target == "/dev/zero" else "a directory"
    (line,) = capsys.readouterr().err.splitlines()
    assert line.endswith(f"error: cannot read {target}: it is {kind}, not a regular file")


def test_many_params_and_drives_parse(tmp_path):
    n = 10_000
    text = "".join(f"param p{k} = {k}.5\n" for k in range(n))
    text += "".join(f"drive d{k}: angle(b) = p{k}*t\n" for k in range(n // 10))
    model = parse(text)
    assert len(model.params) == n and len(model.drives) == n // 10
    assert model.params[-1].name == f"p{n - 1}"
    assert E.evaluate(model.drives[-1].function, {f"p{n // 10 - 1}": 2.0, "t": 3.0}) == 6.0


# ---------------------------------------------------------------------------------------------
# 6. Byte-order mark and line ends


def test_a_byte_order_mark_is_accepted_and_columns_stay_right(tmp_path, registry):
    path = tmp_path / "bom.mech"
    path.write_bytes(b"\xef\xbb\xbf" + crank().encode())
    res = mechdsl.load(path, registry=registry).simulate()
    np.testing.assert_allclose(res["crank.phi"], res["t"], atol=1e-14)
    text = "param r = $\n"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    err = load_error(path, registry)
    assert where(err) == column_of(text, "$") == (1, 11)
    assert format_error(err).splitlines()[1] == "    1 | param r = $"


@pytest.mark.parametrize("newline", ["\r", "\r\n"])
def test_old_mac_and_windows_line_ends(tmp_path, registry, newline):
    text = crank()
    path = tmp_path / "m.mech"
    path.write_bytes(text.replace("\n", newline).encode())
    res = mechdsl.load(path, registry=registry).simulate()
    np.testing.assert_allclose(res["crank.phi"], res["t"], atol=1e-14)
    bad = text.replace("output crank.x", "output crank.x, crank.$")
    path.write_bytes(bad.replace("\n", newline).encode())
    err = load_error(path, registry)
    assert err.message == "unexpected character '$'"
    assert where(err) == column_of(bad, "$")
    assert format_error(err).splitlines()[1].endswith("| output crank.x, crank.$, crank.y, "
                                                      "crank.phi, crank.omega, crank.alpha")


def test_a_bad_byte_after_old_mac_line_ends_is_located(tmp_path):
    path = tmp_path / "m.mech"
    path.write_bytes(b"param a = 1\r# caf\xc3\xa9 \xff\r")
    with pytest.raises(MechError) as info:
        mechdsl.load(path)
    assert info.value.message == "the file is not valid UTF-8 (byte 0xff)"
    assert where(info.value) == (2, 8)  # characters, not bytes: the \u00e9 counts once
