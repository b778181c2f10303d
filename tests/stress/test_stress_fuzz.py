"""A seeded sample of the fuzzer (benchmarks/fuzz.py, whose full runs are 10^5 inputs): hostile
input ends in a result or a located error, never an internal error, a traceback or a hang."""

import importlib.util

from conftest import ROOT


def load_fuzzer():
    spec = importlib.util.spec_from_file_location("fuzz", ROOT / "benchmarks" / "fuzz.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_fuzz_sample_finds_no_defect():
    fuzz = load_fuzzer()
    counts, bad = fuzz.fuzz(300, jobs=1, seed=7, timeout=30)
    assert sum(counts.values()) == 300
    assert not bad, [(kind, data[:200], text[:300]) for kind, data, text in bad]
    assert counts.get("user", 0) > 100 and counts.get("ok", 0) > 5  # both paths exercised


def test_the_fuzzer_sees_a_planted_defect(monkeypatch):
    """The harness itself: an internal error in the pipeline is caught and reported."""
    fuzz = load_fuzzer()
    import mechdsl.compile as compile_module

    def broken(*args, **kwargs):
        raise ZeroDivisionError("planted")

    monkeypatch.setattr(compile_module, "compile_model", broken)
    import mechdsl.api

    monkeypatch.setattr(mechdsl.api, "compile_model", broken)
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        kind, text = fuzz.run_one((ROOT / "examples" / "slider_crank.mech").read_bytes(), d, 10)
    assert kind == "internal" and "ZeroDivisionError: planted" in text
