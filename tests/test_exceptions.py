"""Every error isa raises is an ``isa.IsaError`` and also the builtin that pre-isa code catches."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import isa
from isa import exceptions as E

PACKAGE = Path(isa.__file__).parent
#: Builtins raised on purpose: (file, exception) -> why.
ALLOWED = {
    ("forest/model.py", "TypeError"): "json.dumps' default= hook must raise TypeError for what it cannot encode",
    ("evaluation/linemod.py", "RuntimeError"): "an internal invariant of OpenCV's Linemod broke (a bug, not bad input)",
    ("data/bop.py", "NotImplementedError"): "the abstract frame reader of the lazy frame sequences' base class",
    ("detection/cli.py", "SystemExit"): "a command-line usage error: argparse's way out",
    ("detection/evaluate.py", "SystemExit"): "a command-line usage error: argparse's way out",
    ("scenes/__main__.py", "SystemExit"): "a command-line usage error: argparse's way out",
}


def _builtin_raises():
    import builtins

    names = {n for n in dir(builtins) if isinstance(getattr(builtins, n), type)
             and issubclass(getattr(builtins, n), BaseException)}
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and node.exc is not None:
                exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                if isinstance(exc, ast.Name) and exc.id in names:
                    yield path.relative_to(PACKAGE).as_posix(), exc.id, node.lineno


def test_the_package_raises_no_bare_builtin_exception():
    found = [(f, e, line) for f, e, line in _builtin_raises() if (f, e) not in ALLOWED]
    assert found == [], "raise an isa.exceptions class (also the builtin) instead: " + repr(found)


@pytest.mark.parametrize("cls, builtin", [
    (E.DataError, ValueError), (E.DataNotFoundError, FileNotFoundError), (E.DataNotFoundError, E.DataError),
    (E.InvalidValueError, ValueError), (E.InvalidTypeError, TypeError), (E.InvalidValueError, E.InvalidInputError),
    (E.InvalidTypeError, E.InvalidInputError), (E.MissingDependencyError, ImportError), (E.UsageError, RuntimeError),
])
def test_python_side_errors_are_isa_errors_and_builtins(cls, builtin):
    assert issubclass(cls, E.IsaError) and issubclass(cls, builtin)
    assert getattr(isa, cls.__name__) is cls  # re-exported at the top


def test_raised_errors_carry_both_identities(tmp_path):
    from isa.camera import Intrinsics
    from isa.data.meshes import load_mesh
    from isa.privileged.skeleton import extract_skeleton

    with pytest.raises(FileNotFoundError, match="mesh file not found") as e:
        load_mesh(tmp_path / "absent.off")
    assert isinstance(e.value, E.DataNotFoundError)
    with pytest.raises(E.IsaError, match="focal lengths must be positive") as e:
        Intrinsics(fx=0.0, fy=1.0, cx=0.0, cy=0.0, width=4, height=4)
    assert isinstance(e.value, ValueError)
    with pytest.raises(TypeError, match="expected a trimesh.Trimesh") as e:
        extract_skeleton(np.zeros((3, 3)))
    assert isinstance(e.value, E.InvalidInputError)
