"""The core must not import the UI or torch (DESIGN.md principle 2)."""

import subprocess
import sys


def test_core_imports_neither_textual_nor_torch():
    code = (
        "import sys, stw_tui.session, stw_tui.cli, stw_tui.window, stw_tui.backend, stw_scipy\n"
        "from stw_tui.session import Session\n"
        "s = Session(); s.run_text('dof x\\nconstraint c: x = 1 @ 0\\nobjective o: x\\'\\'\\niterate 2')\n"
        "bad = [m for m in ('textual', 'torch', 'plotext') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def _imports_of(path, package: str, modules: set[str]) -> set[str]:
    """The stw_tui modules a module imports anywhere (inside functions too), except under
    ``if TYPE_CHECKING:`` (annotations only: nothing is imported when the program runs)."""
    import ast

    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only = {id(node) for block in ast.walk(tree)
                   if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
                   for node in ast.walk(block)}
    found = set()
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom):
            parts = package.split(".")
            base = ".".join(parts[:len(parts) - node.level + 1]) if node.level else ""
            target = ".".join(p for p in (base, node.module or "") if p)
            found |= {target} | {f"{target}.{alias.name}" for alias in node.names}
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
    return found & modules


def test_no_two_core_modules_import_each_other():
    """A module that imports one that imports it back (even lazily, inside a function) hides
    which of the two is the lower layer; session -> interpreter -> outcome, never back."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    paths = {}
    for path in (root / "stw_tui").rglob("*.py"):
        rel = path.relative_to(root).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        paths[".".join(parts)] = path
    imports = {}
    for name, path in paths.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        imports[name] = _imports_of(path, package, set(paths)) - {name}
    mutual = sorted(f"{a} <-> {b}" for a in imports for b in imports[a] if a < b and a in imports[b])
    assert mutual == []


def test_no_code_can_evaluate_text_as_python():
    # User text must never reach Python evaluation: no eval/exec/compile builtins, and no sympy
    # or symengine call that parses strings (sympify, parse_expr, S(...)), anywhere in the core
    # or the bundled backends. One S(...) is known: the compiler hands symengine its own sympy
    # trees (never text), and that site is listed here so any other one fails.
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    builtins, parsers = {"eval", "exec", "compile"}, {"sympify", "parse_expr", "S"}
    known = {("stw_tui/compiler.py", "S")}
    found = []
    for path in sorted([*(root / "stw_tui").rglob("*.py"), *(root / "backends").rglob("*.py")]):
        rel = path.relative_to(root).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            if (isinstance(f, ast.Name) and f.id in builtins | parsers) or \
                    (isinstance(f, ast.Attribute) and f.attr in parsers and (rel, f.attr) not in known):
                found.append(f"{rel}:{node.lineno}")
    assert not found, found
