"""Shared fixtures. Unit tests register the built-in plugins directly, so that they do not
depend on what happens to be installed; tests/test_cli.py checks real entry-point discovery."""

from __future__ import annotations

from pathlib import Path

import pytest

import mechdsl
from mechdsl.plugins import build_registry

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def pytest_configure(config):
    """mechdsl and its plugins byte-compiled once, before any test (and, under xdist, by the
    controller, before its workers start). The tests start several hundred interpreters (the
    command line, the fuzzer, the language server, the view), each importing mechdsl: where
    no bytecode was written, as in a fresh clone with PYTHONDONTWRITEBYTECODE set, each would
    compile its hundred modules from source again, about a quarter of a second a process. The
    files go where Python itself would write them (__pycache__, ignored by git); a tree that
    cannot be written is left as it is."""
    import compileall

    if hasattr(config, "workerinput"):
        return
    for folder in (ROOT / "mechdsl", *ROOT.glob("plugins/*/mechdsl_*"),
                   *ROOT.glob("examples/plugins/*/mechdsl_*")):
        compileall.compile_dir(folder, quiet=2)


def load_fuzzer():
    """benchmarks/fuzz.py as a module: its generators of mutated and generated files."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("fuzz", ROOT / "benchmarks" / "fuzz.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["fuzz"] = module  # while its dataclasses are made
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules["fuzz"]
    return module


@pytest.fixture(scope="session")
def registry():
    import mechdsl_cams
    import mechdsl_distance
    import mechdsl_drives
    import mechdsl_gears
    import mechdsl_prismatic
    import mechdsl_revolute
    import mechdsl_rigid

    reg = build_registry([mechdsl_revolute, mechdsl_prismatic, mechdsl_drives, mechdsl_rigid,
                          mechdsl_distance, mechdsl_gears, mechdsl_cams], entry_points=False)
    assert not reg.broken, reg.broken
    return reg


@pytest.fixture
def loads(registry):
    """Parse .mech text with the built-in plugins."""

    def _loads(text: str, name: str = "test.mech"):
        return mechdsl.loads(text, name, registry=registry)

    return _loads


@pytest.fixture
def load_example(registry):
    def _load(name: str):
        return mechdsl.load(EXAMPLES / name, registry=registry)

    return _load


def model_meaning(obj):
    """A parsed model without where its parts were written (spans, the source text): two
    texts mean the same model where these are equal."""
    import dataclasses

    from mechdsl.errors import Source, Span

    if isinstance(obj, (Span, Source)):
        return None
    if dataclasses.is_dataclass(obj):
        return (type(obj).__name__,) + tuple(model_meaning(getattr(obj, f.name))
                                             for f in dataclasses.fields(obj))
    if isinstance(obj, (list, tuple)):
        return tuple(model_meaning(x) for x in obj)
    return obj


#: The longest tests (about 7 to 20 s each, most of it numba compiling, an optimisation's
#: search, a wheel built and installed, a cluster started and interrupted), started first:
#: the parallel workers (-n auto) then end together instead of one of them running a long
#: test alone at the end. Tests that share a module's fixture stay together and in their
#: order: moved apart, two workers would each build it. Here whole modules are moved for
#: that reason (test_optimize.py's coupler synthesis, 17-20 s, and its slider-crank search;
#: test_cluster.py's cluster; test_docs_site.py's site): pytest-xdist's load scheduling
#: sends the first worker the first quarter of its share of the tests (about 170 of 1420
#: with two workers) in one piece, and all of these, some 90 tests, are in it.
SLOW_FIRST = (
    "test_optimize.py::",
    "test_native.py::test_the_compiled_model_is_cached_on_disk",
    "test_cluster.py::",
    "test_packaging.py::test_the_core_wheel_alone",
    "test_dynamics_budget.py::test_a_run_on_a_terminal",
    "test_stress_fuzz.py::",
    "test_docs_site.py::",
    "test_model_is_data.py::test_the_memory_limit_bounds_the_whole_process",
    "test_outputs_safety.py::test_the_csv_writer_holds_bounded_memory",
    "test_cluster_trust.py::test_ctrl_c_at_a_terminal",
)


def pytest_collection_modifyitems(items):
    """The tests of :data:`SLOW_FIRST` first (a stable sort: the rest keep their order)."""
    items.sort(key=lambda item: not any(s in item.nodeid for s in SLOW_FIRST))
