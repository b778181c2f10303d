"""The house's layout holds (docs/architecture.md): data flows one way through the stages, the
command line reaches the solver only through the API, a new output format is one module and
one registry entry.

Every import of mechdsl's own modules is read from the source (those inside functions too,
which is where the heavy ones are), so a lazy import back up fails here as a top-level one
would."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "mechdsl"

#: The stages, lowest first: a module may import its own stage and those before it. A stage
#: is a package under mechdsl/ or a flat module (by its name).
STAGES = (
    ("base", {"errors", "memory", "reading", "writing", "results"}),
    ("grammar", {"grammar"}),
    ("symbolic", {"symbolic"}),
    ("plugins", {"plugins", "functions"}),
    ("compiled", {"compiled"}),
    ("solve", {"solve"}),
    ("outputs", {"outputs"}),
    ("study", {"study"}),
    ("use cases", {"api", "diagnostics", "testing"}),
    ("surfaces", {"commands", "cli", "lsp", "view", "__main__", "__init__"}),
)
LEVEL = {unit: k for k, (_, units) in enumerate(STAGES) for unit in units}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _unit(module: str) -> str:
    """The stage unit of a module: its package under mechdsl, or its flat module's name
    (mechdsl itself: its __init__)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imports(path: Path) -> list[tuple[str, int]]:
    """The mechdsl modules that ``path`` imports, with the line, every import statement of
    the file (inside functions too)."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names = [f"{target}.{a.name}" for a in node.names]
            # "from . import payload" names a module; "from .x import f" a module's name
            targets = [n for n in names if (PACKAGE.parent / (n.replace(".", "/") + ".py")
                                            ).exists() or (PACKAGE.parent / n.replace(".", "/")
                                                           ).is_dir()] or [target]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            continue
        found += [(t, node.lineno) for t in targets if t == "mechdsl" or
                  t.startswith("mechdsl.")]
    return found


def _sources() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def test_every_module_belongs_to_a_stage():
    units = {_unit(_module_name(p)) for p in _sources()}
    assert units <= set(LEVEL), sorted(units - set(LEVEL))


def test_no_stage_imports_a_later_one():
    upward = []
    for path in _sources():
        here = _unit(_module_name(path))
        for target, line in imports(path):
            there = _unit(target)
            if LEVEL[there] > LEVEL[here]:
                upward.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {here} "
                              f"({STAGES[LEVEL[here]][0]}) imports {target} "
                              f"({STAGES[LEVEL[there]][0]})")
    assert not upward, "\n".join(upward)


@pytest.mark.parametrize("surface", ["commands.py", "cli.py", "view/session.py",
                                     "view/server.py", "lsp.py", "__init__.py",
                                     "__main__.py"])
def test_the_command_line_and_the_editors_reach_the_solver_only_through_the_api(surface):
    reached = [f"line {line}: {target}" for target, line in imports(PACKAGE / surface)
               if _unit(target) in ("solve", "study")]
    assert not reached, reached


def test_the_checker_finds_a_lazy_import_back_up(tmp_path, monkeypatch):
    # the checks above must see an import inside a function, relative or absolute
    fake = PACKAGE / "compiled" / "_layout_probe.py"
    monkeypatch.setattr(Path, "read_text", lambda self, encoding=None: (
        "def f():\n    from ..solve import simulate\n    import mechdsl.api\n"
        if self == fake else Path.open(self, encoding=encoding).read()))
    assert imports(fake) == [("mechdsl.solve", 2), ("mechdsl.api", 3)]


def test_the_page_format_is_one_module_and_one_registry_entry():
    """``--html`` is written, sized for the memory plan, flagged on the command line and
    summarised from its registry entry and its module alone: nothing else names it."""
    from mechdsl.outputs import FORMATS

    page = FORMATS["page"]
    assert page.writer.startswith("html:") and page.memory.startswith("html:") \
        and page.summary.startswith("html:")
    for where in ("cli.py", "commands.py", "memory.py", "api.py", "solve/memory.py"):
        text = (PACKAGE / where).read_text(encoding="utf-8")
        assert not re.search(r"html|write_page", text), where


def test_the_command_line_flags_are_the_registry(capsys):
    """Every flag of ``mechdsl run`` that writes a file is a format's entry, and every
    format has its flag: the options that take an output path, read from the parser the
    command line builds, are exactly the registry's."""
    from mechdsl.cli import main
    from mechdsl.outputs import FORMATS

    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    takes_file = set(re.findall(r"(--?[a-z][a-z-]*) OUT\.[a-z]+", text))
    registry = {f.option for f in FORMATS.values()} | {a for f in FORMATS.values()
                                                       for a in f.aliases}
    assert takes_file == registry, (takes_file, registry)


def test_the_memory_plan_adds_each_formats_own_estimate(tmp_path, monkeypatch, capsys):
    """The run's memory plan reads the page's estimate from its registry entry: an estimate
    of a PiB refuses the run before it starts (exit 1, the figure named), and nothing is
    written."""
    from dataclasses import replace

    from mechdsl import outputs
    from mechdsl.cli import main
    from mechdsl.outputs import html

    monkeypatch.setattr(html, "probe_memory", lambda system, path, settings:
                        {"the probe": 2**50}, raising=False)
    monkeypatch.setitem(outputs.FORMATS, "page",
                        replace(outputs.FORMATS["page"], memory="html:probe_memory"))
    page = tmp_path / "page.html"
    example = PACKAGE.parent / "examples" / "slider_crank.mech"
    assert main(["run", str(example), "--html", str(page), "-q"]) == 1
    err = capsys.readouterr().err
    assert "drawings and exports 1024.0 TiB" in err and "more than the limit" in err, err
    assert not page.exists()
    monkeypatch.undo()
    assert main(["run", str(example), "--html", str(page), "-q"]) == 0 and page.exists()


def _code_in(obj, path: str = "system", seen: set | None = None) -> list[str]:
    """Where ``obj`` (a compiled model) holds code: functions, code objects, generated
    kernels, anything callable but a plugin's type and a function-valued argument (its
    expressions), recursing through dataclasses, mappings and sequences."""
    import dataclasses
    import types
    from collections.abc import Mapping

    import numpy as np

    from mechdsl.functions import ExprFunction
    from mechdsl.plugins.contract import ConstraintType

    seen = set() if seen is None else seen
    if id(obj) in seen or isinstance(obj, (str, bytes, int, float, bool, type(None),
                                            np.ndarray, np.generic)):
        return []
    seen.add(id(obj))
    if isinstance(obj, (ConstraintType, ExprFunction)):
        return []
    if isinstance(obj, (types.FunctionType, types.MethodType, types.CodeType,
                        types.BuiltinFunctionType, types.ModuleType)) or (
            callable(obj) and not dataclasses.is_dataclass(obj)):
        return [f"{path}: {type(obj).__name__}"]
    found = []
    if dataclasses.is_dataclass(obj):
        for f in dataclasses.fields(obj):
            found += _code_in(getattr(obj, f.name), f"{path}.{f.name}", seen)
        found += [f"{path}.{k}: cached {type(v).__name__}" for k, v in vars(obj).items()
                  if k not in {f.name for f in dataclasses.fields(obj)}
                  and not isinstance(v, (np.ndarray, list, int))]
    elif isinstance(obj, Mapping):
        for k, v in obj.items():
            found += _code_in(v, f"{path}[{k!r}]", seen)
    elif isinstance(obj, (tuple, list)):
        for k, v in enumerate(obj):
            found += _code_in(v, f"{path}[{k}]", seen)
    return found


@pytest.mark.parametrize("name", ["slider_crank.mech", "cam_roller.mech", "rod_sweep.mech",
                                  "andrews.mech", "start_from_rest.mech", "offset_stroke.mech"])
def test_the_compiled_models_data_holds_no_generated_code(name):
    """The compiled model is plain data; its code is held apart by its Kernels (the
    architecture page). Solved first, so that every plan a run makes on first use exists,
    and then checked: nothing callable in the System, and it pickles whole (a function-valued
    argument as its expressions)."""
    import pickle

    import mechdsl
    from mechdsl.compiled.kernels import Kernels
    from mechdsl.solve import simulate

    kernels = mechdsl.load(Path(__file__).resolve().parent.parent / "examples" / name).compile()
    assert isinstance(kernels, Kernels) and kernels.fused is not None
    assert simulate(kernels).ok
    system = kernels.system
    assert _code_in(system) == []
    again = pickle.loads(pickle.dumps(system))
    assert again.body_names == system.body_names and again.n == system.n
    assert np.array_equal(again.guess, system.guess)


def test_the_code_finder_finds_code_in_a_system(load_example):
    """The check above can fail: a System with a generated function in it is found."""
    from dataclasses import replace

    kernels = load_example("slider_crank.mech").compile()
    planted = replace(kernels.system, env={"f": kernels.drive_functions[0].f})
    assert _code_in(planted) == ["system.env['f']: function"]
