"""The package layout's promises: every module imports without touching an old path, the old flat
paths still work (and warn), importing loads no OpenGL / OpenCV and changes no environment, no
import cycle between modules or subpackages, `python -m isa` dispatches, files stay short."""

from __future__ import annotations

import ast
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import isa
from isa import _compat
from isa.__main__ import COMMANDS, main

PACKAGE = Path(isa.__file__).parent
MAX_LINES = 600


def _modules() -> dict[str, Path]:
    """Every module of the package (dotted name -> file), from the source tree."""
    out = {"isa": PACKAGE / "__init__.py"}
    for info in pkgutil.walk_packages([str(PACKAGE)], prefix="isa."):
        if info.name == "isa._core":
            continue
        spec = info.module_finder.find_spec(info.name.rpartition(".")[2])
        out[info.name] = Path(spec.origin)
    return out


def _run(code: str, *args: str, env_drop: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in env_drop}
    env["PYTHONPATH"] = os.pathsep.join([str(PACKAGE.parent), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, *args, "-c", code] if code else [sys.executable, *args],
                          capture_output=True, text=True, env=env, timeout=120)


def test_every_module_imports_without_old_paths_opengl_opencv_or_environment_changes():
    # A fresh interpreter: imports every module with warnings as errors (an internal caller of an
    # old path would raise the compat DeprecationWarning), then reports what got loaded.
    names = sorted(_modules())
    code = (
        "import importlib, json, os, sys, warnings\n"
        "warnings.simplefilter('error')\n"
        "before = dict(os.environ)\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name)\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('pyrender', 'OpenGL', 'cv2', 'pyglet'))\n"
        "changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))\n"
        "print(json.dumps({'heavy': heavy, 'changed': changed}))\n"
    )
    r = _run(code, env_drop=("PYOPENGL_PLATFORM",))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out == {"heavy": [], "changed": []}
    assert len(names) > 40  # the walk found the subpackages' modules, not only the top level


def test_subpackage_import_is_light():
    code = ("import sys, isa.data, isa.render, isa.privileged, isa.forest, isa.detection, isa.evaluation, isa.report\n"
            "print(sorted(m for m in sys.modules if m.startswith('isa.') and m.count('.') > 1\n"
            "             and not m.startswith('isa._core.')))")
    r = _run(code)
    assert r.returncode == 0, r.stderr
    # No module of any subpackage loaded until a name is used (the compiled core's own
    # submodules, _errors and _testing, are registered with it and cost nothing).
    assert r.stdout.strip() == "[]"


def test_subpackages_re_export_their_modules_names():
    import isa.data.bop
    import isa.detection.planes
    import isa.render.renderer
    from isa.data import FrameSequence
    from isa.detection import remove_planes
    from isa.forest import Forest, ForestParams
    from isa.render import DepthRenderer

    assert FrameSequence is isa.data.bop.FrameSequence
    assert remove_planes is isa.detection.planes.remove_planes
    assert DepthRenderer is isa.render.renderer.DepthRenderer
    assert Forest.__module__ == "isa.forest.model" and ForestParams.__module__ == "isa.forest.model"
    for pkg in ("data", "render", "privileged", "forest", "detection", "evaluation", "report"):
        mod = __import__(f"isa.{pkg}", fromlist=["*"])
        for name in mod.__all__:
            assert getattr(mod, name) is not None, f"isa.{pkg}.{name}"


def test_old_flat_paths_alias_the_new_modules_and_warn():
    import isa.data.bop
    import isa.report.figures.poses

    for old, new in [("isa.bop", isa.data.bop), ("isa.figures.poses", isa.report.figures.poses)]:
        for name in ("isa.bop", "isa.figures", "isa.figures.poses"):
            sys.modules.pop(name, None)
        with pytest.warns(DeprecationWarning) as record:
            mod = __import__(old, fromlist=["*"])
        assert f"{old} moved to {new.__name__}" in [str(w.message).split(";")[0] for w in record]
        assert mod is new  # the same module object: one state, isinstance works across paths
    sys.modules.pop("isa.sunrgbd", None)
    if "sunrgbd" in vars(isa):
        delattr(isa, "sunrgbd")  # else `from isa import` finds the attribute and imports nothing
    with pytest.warns(DeprecationWarning, match="isa.sunrgbd moved to isa.data.sunrgbd"):
        from isa import sunrgbd
    assert sunrgbd is sys.modules["isa.data.sunrgbd"]
    for old in _compat.MOVED:
        assert _compat.new_name(f"isa.{old}") is not None
        __import__(_compat.MOVED[old])  # every target exists
    assert _compat.new_name("isa.pipeline") is None and _compat.new_name("numpy") is None


def test_old_commands_still_run():
    r = _run("", "-W", "default::DeprecationWarning", "-m", "isa.dataset", "--help")
    assert r.returncode == 0, r.stderr
    assert "usage: python -m isa dataset" in r.stdout and "isa.dataset moved to isa.render.dataset" in r.stderr
    r = _run("", "-m", "isa.detection", "--help")
    assert r.returncode == 0, r.stderr
    assert "usage: python -m isa detect-real" in r.stdout and "python -m isa detect-real" in r.stderr


def _module_level_imports(name: str, path: Path, known: set[str]) -> set[str]:
    """isa modules imported when ``name`` is imported (top-level statements only: imports inside
    functions are lazy by design; ``if TYPE_CHECKING:`` blocks never run)."""
    out = set()
    tree = ast.parse(path.read_text())
    nodes = [n for top in tree.body if not isinstance(top, ast.If) for n in ast.walk(top)
             if not isinstance(top, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]
    for n in nodes:
        if isinstance(n, ast.Import):
            out |= {a.name for a in n.names if a.name in known}
        elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module and n.module.split(".")[0] == "isa":
            for a in n.names:
                full = f"{n.module}.{a.name}"
                out.add(full if full in known else n.module)
    return {m for m in out if m in known and m != name}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(v):
        state[v] = 1
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if state.get(w) == 1:
                return stack[stack.index(w):] + [w]
            if w not in state and (c := visit(w)):
                return c
        state[v] = 2
        stack.pop()
        return None

    for v in sorted(graph):
        if v not in state and (c := visit(v)):
            return c
    return None


def test_no_import_cycle_between_modules_or_subpackages():
    mods = _modules()
    graph = {n: _module_level_imports(n, p, set(mods)) for n, p in mods.items()}
    assert _cycle(graph) is None

    def unit(n):  # a subpackage, or a top-level module; the package itself only re-exports
        parts = n.split(".")
        return parts[1] if len(parts) > 1 else None

    units: dict[str, set[str]] = {}
    for n, deps in graph.items():
        for d in deps:
            if unit(n) and unit(d) and unit(n) != unit(d):
                units.setdefault(unit(n), set()).add(unit(d))
    assert _cycle(units) is None
    assert "data" in units["render"] and "render" not in units.get("data", set())  # the graph is real


def test_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_python_m_isa_dispatches_to_the_commands(capsys):
    for name, (module, _) in COMMANDS.items():
        assert callable(__import__(module, fromlist=["main"]).main), name
        with pytest.raises(SystemExit) as e:
            main([name, "--help"])
        assert e.value.code == 0
        assert f"usage: python -m isa {name}" in capsys.readouterr().out
    for argv in ([], ["no-such-command"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2


def test_long_files_say_why():
    for name, path in _modules().items():
        n = len(path.read_text().splitlines())
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        assert n <= MAX_LINES or "Longer than 600 lines:" in doc, f"{name}: {n} lines and no reason at its top"


def test_reexports_are_the_modules_all_and_refuse_a_name_exported_twice(tmp_path, monkeypatch):
    import importlib
    import sys

    from isa._reexport import lazy_reexport

    for pkg in ("isa.data", "isa.detection", "isa.evaluation", "isa.forest", "isa.privileged", "isa.render"):
        package = importlib.import_module(pkg)
        for name in package.__all__:  # each flat name is the object its module defines
            obj = getattr(package, name)
            if not isinstance(obj, type(sys)):
                assert any(getattr(importlib.import_module(f"{pkg}.{m}"), name, None) is obj
                           for m in package.__all__ if isinstance(getattr(package, m), type(sys)))
    root = tmp_path / "twice"
    root.mkdir()
    (root / "__init__.py").write_text("")
    (root / "a.py").write_text('__all__ = ["f"]\ndef f(): pass\n')
    (root / "b.py").write_text('__all__ = ["f"]\ndef f(): pass\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.import_module("twice")
    from isa.exceptions import DataError

    with pytest.raises(DataError, match="'f' is exported by both a and b"):
        lazy_reexport("twice", ["a", "b"])
