"""A seeded sample of the fuzzer (benchmarks/fuzz.py, whose full runs are 10^5 inputs): hostile
input ends in a result or a located error, never an internal error, a traceback or a hang, and
does nothing a data file may not make happen. And the harness itself: each kind of defect it
looks for is found when one is planted in the pipeline."""

import os
import signal
import sys
import tempfile

import pytest

from conftest import ROOT, load_fuzzer

SLIDER = (ROOT / "examples" / "slider_crank.mech").read_bytes()
STEP = ["--step", "0.01"]

def test_a_fuzz_sample_finds_no_defect():
    fuzz = load_fuzzer()
    stats = {}
    counts, bad = fuzz.fuzz(300, jobs=1, seed=7, timeout=30, stats=stats)
    assert sum(counts.values()) == 300
    assert not bad, [(f.kind, f.case.describe(), f.text[:600]) for f in bad]
    assert counts.get("user", 0) > 100 and counts.get("ok", 0) > 5  # both paths exercised
    # the hostile generator took its share, every class of it, and was not all refused
    assert 30 <= stats["hostile"]["n"] <= 100
    assert set(stats["hostile classes"]) == {name for name, _, _ in fuzz.HOSTILE}
    assert stats["hostile"]["kinds"].get("ok", 0) > 5


def test_the_hostile_generator_is_deterministic_and_covers_its_classes():
    fuzz = load_fuzzer()
    import random

    labels = set()
    for name, _, make in fuzz.HOSTILE:
        for i in range(40):
            a, b = make(random.Random(f"{name}{i}")), make(random.Random(f"{name}{i}"))
            assert (a.data, a.args, a.setup) == (b.data, b.args, b.setup)
            labels.add(a.label.split(" ")[0])
    # plugins, tables, shapes, corrupt meshes, deep expressions, long lines, BOM and line
    # endings, outputs, options
    for label in ("plugin", "table", "shape", "mesh", "deep", "long", "BOM", "CR", "options"):
        assert label in labels, (label, sorted(labels))


def test_the_fuzzer_sees_a_planted_defect(monkeypatch):
    """The harness itself: an internal error in the pipeline is caught and reported."""
    fuzz = load_fuzzer()
    import mechdsl.compiled.compile as compile_module

    def broken(*args, **kwargs):
        raise ZeroDivisionError("planted")

    monkeypatch.setattr(compile_module, "compile_model", broken)
    import mechdsl.api

    monkeypatch.setattr(mechdsl.api, "compile_model", broken)

    with tempfile.TemporaryDirectory() as d:
        kind, text = fuzz.run_one((ROOT / "examples" / "slider_crank.mech").read_bytes(), d, 10)
    assert kind == "internal" and "ZeroDivisionError: planted" in text


# -- each kind of defect, planted ----------------------------------------------------------------

def _wrap_write_csv(monkeypatch, before=None, after=None):
    """write_csv as it is, with something done before or after it."""
    import mechdsl.outputs.csv

    real = mechdsl.outputs.csv.write_csv

    def planted(results, target):
        if before:
            before(target)
        real(results, target)
        if after:
            after(target)

    monkeypatch.setattr(mechdsl.outputs.csv, "write_csv", planted)


def plant_imported(fuzz, monkeypatch):
    """A plugin line imports its module: the model's folder on sys.path, nothing refused."""
    import mechdsl.api

    def allow_all(requested, allowed=()):
        sys.path.insert(0, os.getcwd())
        return []

    monkeypatch.setattr(mechdsl.api, "allowed_plugins", allow_all)
    monkeypatch.delitem(sys.modules, "this", raising=False)
    monkeypatch.setattr(sys, "path", list(sys.path))
    module = "fuzzplug_planted"
    code = f"open({module!r} + '.ran', 'w').close()\n"
    return fuzz.Case(b'plugin "this"\nplugin "fuzzplug_planted"\n' + SLIDER, STEP,
                     setup=[(f"{module}.py", ("file", code.encode(), None))],
                     plugins=("this", module), expect=frozenset({1})), [
        "imported fuzzplug_planted, this", "the module beside the model ran: fuzzplug_planted",
        "a module printed on import", "sys.path changed"]


def plant_clobbered(fuzz, monkeypatch):
    """-o naming the model is not refused: write_csv writes the CSV over it."""
    import mechdsl.commands

    monkeypatch.setattr(mechdsl.commands, "check_distinct", lambda *a, **k: None)
    return fuzz.Case(SLIDER, ["-o", "{model}", *STEP], expect=frozenset({1})), \
        ["fuzz.mech changed"]


def plant_echoed(fuzz, monkeypatch):
    """A table's bad field is shown whole."""
    import mechdsl.compiled.files

    monkeypatch.setattr(mechdsl.compiled.files, "excerpt", lambda text, width=12: repr(text))
    secret = b"0,1\n" + b"s3cr3t" * 10 + b",2\n"
    data = SLIDER.replace(b"pi/4 + omega*t", b'pi/4 + omega*t + 0*table("t.csv", t)')
    return fuzz.Case(data, STEP, setup=[("t.csv", ("file", secret, None))],
                     secrets=("t.csv",), expect=frozenset({1})), ["s3cr3ts3cr3t"]


def plant_stray(fuzz, monkeypatch):
    _wrap_write_csv(monkeypatch, before=lambda target: open(".mechdsl-planted.tmp", "w").close())
    return fuzz.Case(SLIDER, ["-o", "out.csv", *STEP], writes=("out.csv",)), \
        [".mechdsl-planted.tmp"]


def plant_printed(fuzz, monkeypatch):
    """Something writes on file descriptor 1 (as a C library or meshio would)."""
    _wrap_write_csv(monkeypatch, before=lambda target: os.write(1, b"planted output\n"))
    return fuzz.Case(SLIDER, ["-o", "out.csv", *STEP], writes=("out.csv",)), \
        ["planted output"]


def plant_mode(fuzz, monkeypatch):
    _wrap_write_csv(monkeypatch, after=lambda target: os.chmod(target, 0o600))
    mode = 0o640
    return fuzz.Case(SLIDER, ["-o", "old.csv", *STEP], setup=[
        ("old.csv", ("file", b"old\n", mode))], writes=("old.csv",), modes={"old.csv": mode}), \
        ["old.csv written with mode 600, not 640"]


def plant_accepted(fuzz, monkeypatch):
    """--frames 0 is not refused."""
    import mechdsl.commands

    monkeypatch.setattr(mechdsl.commands, "_check_targets", lambda args: None)
    return fuzz.Case(SLIDER, ["--frames", "0", *STEP], expect=frozenset({1})), \
        ["exit 0, but it must exit with 1"]


def plant_differs(fuzz, monkeypatch):
    """A model with CRLF line endings is refused."""
    import mechdsl.reading
    from mechdsl.errors import MechError

    real = mechdsl.reading.read_data

    def planted(*args, **kwargs):
        data = real(*args, **kwargs)
        if b"\r\n" in data:
            raise MechError("planted: CRLF refused")
        return data

    monkeypatch.setattr(mechdsl.reading, "read_data", planted)
    original = fuzz.Case(SLIDER, STEP)
    return fuzz.Case(SLIDER.replace(b"\n", b"\r\n"), STEP, like=original), \
        ["exit 1; the original exits 0"]


def plant_flooded(fuzz, monkeypatch):
    _wrap_write_csv(monkeypatch, before=lambda target: sys.stderr.write("x" * 200_000))
    return fuzz.Case(SLIDER, ["-o", "out.csv", *STEP], writes=("out.csv",)), \
        ["200,000 characters of messages"]


def plant_hang(fuzz, monkeypatch):
    import time

    _wrap_write_csv(monkeypatch, before=lambda target: time.sleep(30))
    return fuzz.Case(SLIDER, ["-o", "out.csv", *STEP], writes=("out.csv",)), ["no end within"]


PLANTED = {"imported": plant_imported, "clobbered": plant_clobbered, "echoed": plant_echoed,
           "stray": plant_stray, "printed": plant_printed, "mode": plant_mode,
           "accepted": plant_accepted, "differs": plant_differs, "flooded": plant_flooded,
           "hang": plant_hang}


@pytest.mark.parametrize("kind", sorted(PLANTED))
def test_the_fuzzer_sees_each_kind_of_defect(kind, monkeypatch):
    fuzz = load_fuzzer()
    case, clues = PLANTED[kind](fuzz, monkeypatch)
    with tempfile.TemporaryDirectory() as d:
        found, text = fuzz.run_one(case, d, 2 if kind == "hang" else 30)
        assert os.listdir(d) == []  # the input's folder is removed, whatever it left
    assert found == kind, text[:2000]
    for clue in clues:
        assert clue in text, (clue, text[:2000])
    assert "this" not in sys.modules or kind != "imported"  # the harness forgets the import


def test_the_same_input_without_the_planted_defect_is_clean():
    """The planted cases are sound: without the plant none of them is a defect."""
    fuzz = load_fuzzer()
    for kind, plant in sorted(PLANTED.items()):
        with pytest.MonkeyPatch.context() as mp:
            case, _ = plant(fuzz, mp)
        with tempfile.TemporaryDirectory() as d:
            found, text = fuzz.run_one(case, d, 30)
        assert found in ("ok", "user"), (kind, found, text[:2000])


def test_a_worker_that_dies_costs_one_input_each_and_is_reported(monkeypatch):
    """With several jobs, a worker killed by a signal (a segmentation fault, say) is a
    'crash' of the input it was on; the run goes on with the other inputs."""
    fuzz = load_fuzzer()
    monkeypatch.setitem(sys.modules, "fuzz", fuzz)  # failures are pickled by reference
    import mechdsl.cli

    real = mechdsl.cli.main

    def planted(argv):
        if os.path.getsize(argv[1]) % 3 == 0:  # a third of the inputs, say
            os.kill(os.getpid(), signal.SIGKILL)
        return real(argv)

    monkeypatch.setattr(mechdsl.cli, "main", planted)
    counts, bad = fuzz.fuzz(12, jobs=2, seed=3, timeout=30)
    assert sum(counts.values()) == 12
    assert counts.get("crash", 0) >= 1
    assert all(f.kind == "crash" and "SIGKILL" in f.text for f in bad)
    assert counts["crash"] < 12  # the others ran
