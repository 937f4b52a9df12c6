"""Every public class, function and method has a docstring saying what it is for (issue 14).

Public: a module-level or class-level ``def``/``class`` whose name does not start with ``_``
(functions defined inside functions are not API). Textual's hooks need none: the framework calls
them by name, and the name says when (``compose``, ``on_*``, ``action_*``, ``watch_*``, ``render*``).
A method that implements or overrides a documented method of a base class in this code base needs
none of its own: ``help()`` and ``inspect.getdoc`` show the base's, as for ``LinearAlgebra``'s
implementations. Each area is one case, so a failure lists exactly what is missing there; the areas being edited in
parallel are expected failures until that work merges, so the test shows what is left.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
HOOK_PREFIXES = ("on_", "action_", "watch_", "render")
HOOKS = {"compose"}
PENDING = pytest.mark.xfail(strict=False,
                            reason="docstrings pending after the parallel work in these files merges")

# area -> the files it holds (relative to ROOT); each file in exactly one area (checked below)
AREAS: dict[str, list[str]] = {
    "stw_tui (top level)": ["stw_tui/*.py"],
    "stw_tui/sym": ["stw_tui/sym/**/*.py"],
    "stw_tui/sos": ["stw_tui/sos/*.py"],
    "stw_tui/session": ["stw_tui/session/*.py"],
    "stw_tui/cli": ["stw_tui/cli/**/*.py"],
    "stw_tui/app": ["stw_tui/app/**/*.py"],
    "stw_tui/sos/sqp": ["stw_tui/sos/sqp/**/*.py"],
    "stw_tui/sos/backend.py": ["stw_tui/sos/backend.py"],
    "stw_tui/session/autosave.py": ["stw_tui/session/autosave.py"],
    "stw_tui/session/interpreter.py": ["stw_tui/session/interpreter.py"],
    "stw_tui/session/resume.py": ["stw_tui/session/resume.py"],
    "backends": ["backends/**/*.py"],
}
PENDING_AREAS: set[str] = set()   # areas being edited in parallel, expected to fail until merged


def _is_hook(name: str) -> bool:
    return name in HOOKS or name.startswith(HOOK_PREFIXES)


def documented_methods(sources) -> dict[str, tuple[list[str], set[str]]]:
    """class name -> (its bases' names, its methods with a docstring), over ``sources``."""
    classes: dict[str, tuple[list[str], set[str]]] = {}
    for source in sources:
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.ClassDef):
                bases = [b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases]
                docs = {f.name for f in node.body if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                        and ast.get_docstring(f) is not None}
                old_bases, old_docs = classes.get(node.name, ([], set()))
                classes[node.name] = (old_bases + bases, old_docs | docs)
    return classes


def _inherits_doc(classes, cls: str, method: str, seen=()) -> bool:
    bases = classes.get(cls, ([], set()))[0]
    return any(method in classes.get(b, ([], set()))[1] or
               (b not in seen and _inherits_doc(classes, b, method, (*seen, b))) for b in bases)


def missing_docstrings(source: str, classes=None) -> list[str]:
    """Qualified names of the public classes, functions and methods of ``source`` without a
    docstring (Textual hooks allowed on methods; with ``classes`` from :func:`documented_methods`,
    so is a method whose base class documents it)."""
    found: list[str] = []
    classes = classes or {}

    def visit(node: ast.AST, prefix: str, in_class: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                continue
            if child.name.startswith("_"):
                continue
            name = prefix + child.name
            is_class = isinstance(child, ast.ClassDef)
            method = in_class and not is_class
            owner = prefix[:-1].rsplit(".", 1)[-1] if in_class else ""
            if ast.get_docstring(child) is None and not (method and _is_hook(child.name)) \
                    and not (method and _inherits_doc(classes, owner, child.name)):
                found.append(name)
            if is_class:
                visit(child, name + ".", True)

    visit(ast.parse(source), "", False)
    return found


def _area_files() -> dict[str, set[Path]]:
    """The files of each area; a file matched by a narrower area (sos/sqp) leaves the wider one."""
    files = {area: {p for pattern in patterns for p in ROOT.glob(pattern)} for area, patterns in AREAS.items()}
    for area, paths in files.items():
        for other, other_paths in files.items():
            if other != area and other.startswith(area + "/"):
                paths -= other_paths
    return files


def _missing_in(area: str) -> list[str]:
    every = set(ROOT.glob("stw_tui/**/*.py")) | set(ROOT.glob("backends/**/*.py"))
    classes = documented_methods(p.read_text(encoding="utf-8") for p in sorted(every))
    out = []
    for path in sorted(_area_files()[area]):
        rel = path.relative_to(ROOT)
        out += [f"{rel}: {name}" for name in missing_docstrings(path.read_text(encoding="utf-8"), classes)]
    return out


@pytest.mark.parametrize("area", [pytest.param(a, marks=PENDING) if a in PENDING_AREAS else a for a in AREAS])
def test_public_names_have_docstrings(area):
    missing = _missing_in(area)
    assert missing == [], f"{len(missing)} public names in {area} lack a docstring:\n" + "\n".join(missing)


def test_every_module_is_in_exactly_one_area():
    files = _area_files()
    assert all(files.values()), [a for a, f in files.items() if not f]
    placed = [p for paths in files.values() for p in paths]
    every = set(ROOT.glob("stw_tui/**/*.py")) | set(ROOT.glob("backends/**/*.py"))
    assert sorted(placed) == sorted(every)


def test_the_check_finds_what_is_missing():
    source = '''
def documented():
    """Yes."""

def bare():
    def inner():   # local: not API
        pass

def _private():
    pass

class Panel:
    def compose(self):
        pass

    def on_mount(self):
        pass

    def refresh_rows(self):
        pass

    class Inner:
        """Documented."""

        def __init__(self):
            pass

        def act(self):
            pass

def on_result():
    pass
'''
    assert missing_docstrings(source) == ["bare", "Panel", "Panel.refresh_rows", "Panel.Inner.act", "on_result"]


def test_an_override_takes_its_base_classes_docstring():
    source = '''
class Algebra:
    """Base."""

    def solve(self):
        """Documented once, here."""

    def scale(self):
        pass

class Sparse(Algebra):
    """Implementation."""

    def solve(self):
        return 1

    def scale(self):
        return 2

    def extra(self):
        return 3
'''
    classes = documented_methods([source])
    assert missing_docstrings(source, classes) == ["Algebra.scale", "Sparse.scale", "Sparse.extra"]
