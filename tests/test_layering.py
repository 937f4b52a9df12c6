"""The core must not import the UI or torch (DESIGN.md principle 2)."""

import subprocess
import sys


def test_core_imports_neither_textual_nor_torch():
    code = (
        "import sys, stw_tui.session.session, stw_tui.cli.main, stw_tui.sos.window, stw_tui.sos.backend, stw_scipy\n"
        "from stw_tui.session.session import Session\n"
        "s = Session(); s.run_text('dof x\\nconstraint c: x = 1 @ 0\\nobjective o: x\\'\\'\\niterate 2')\n"
        "bad = [m for m in ('textual', 'torch', 'plotext') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_a_replay_and_solve_import_only_what_they_use():
    """The cold start (issue 10): the survey engines (multiprocessing) and the `show` printer
    load when those commands first run."""
    lazy = ("stw_tui.session.survey_session", "stw_tui.session.show", "concurrent.futures.process")
    code = ("import sys\nfrom stw_tui.session.session import Session\n"
            "s = Session(); s.run_text('dof x = 0.5\\nconstraint c: x = 1 @ 0\\n"
            "objective o: x\\'\\'\\niterate 2\\nprint x @ 0.5')\n"
            f"print(sorted(m for m in {lazy!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def _imports_of(path, package: str, modules: set[str], typing_too: bool = False) -> set[str]:
    """The modules among ``modules`` that a module imports anywhere (inside functions too),
    relative imports from ``package``; except under ``if TYPE_CHECKING:`` (annotations only:
    nothing is imported when the program runs) unless ``typing_too``."""
    import ast

    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only = set() if typing_too else {
        id(node) for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test) for node in ast.walk(block)}
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


def _core_modules() -> dict:
    """Dotted module name -> file, for every module of stw_tui (a package is its __init__.py)."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    paths = {}
    for path in (root / "stw_tui").rglob("*.py"):
        rel = path.relative_to(root).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        paths[".".join(parts)] = path
    return paths


def test_no_two_core_modules_import_each_other():
    """A module that imports one that imports it back (even lazily, inside a function) hides
    which of the two is the lower layer; session -> interpreter -> outcome, never back."""
    paths = _core_modules()
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
    known = {("stw_tui/sym/compiler.py", "S")}
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


# The layers of ARCHITECTURE.md, bottom up, and what each may import. An import anywhere in a
# module counts: at the top, inside a function, or under TYPE_CHECKING.
LAYERS = {
    "stw_tui.sym": set(),
    "stw_tui.sos": {"stw_tui.sym"},
    "stw_tui.session": {"stw_tui.sym", "stw_tui.sos"},
    "stw_tui.cli": {"stw_tui.sym", "stw_tui.sos", "stw_tui.session", "stw_tui.app"},
    "stw_tui.app": {"stw_tui.sym", "stw_tui.sos", "stw_tui.session"},
    "backends": {"stw_tui.sym", "stw_tui.sos"},
}
THIRD_PARTY_HOMES = {"textual": ("stw_tui.app",), "textual_plotext": ("stw_tui.app",),
                     "torch": ("backends",), "casadi": ("backends",)}


def _all_imports(path):
    """Every module a file imports by absolute name (a relative import stays in its own package,
    so in its own layer)."""
    import ast

    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0:
                names.add(node.module)
        elif isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
    return names


def _layer_of(module: str) -> str | None:
    for layer in LAYERS:
        if module == layer or module.startswith(layer + "."):
            return layer
    if module.split(".")[0] in ("stw_scipy", "stw_torch", "stw_ipopt"):
        return "backends"
    return None


def test_layers_import_only_downwards():
    """sym <- sos <- session <- app/cli, backends on sos: no arrow runs the other way, and Textual,
    torch and casadi stay in their homes (ARCHITECTURE.md)."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    files = [*(root / "stw_tui").rglob("*.py"), *(root / "backends").rglob("*.py")]
    assert len(files) > 60
    wrong = []
    for path in files:
        rel = path.relative_to(root)
        module = ".".join(rel.with_suffix("").parts)
        own = _layer_of(module if rel.parts[0] == "stw_tui" else rel.parts[1])
        assert own is not None or rel == Path("stw_tui/__init__.py"), rel
        for name in _all_imports(path):
            target = _layer_of(name)
            if target is not None and target != own and target not in LAYERS.get(own, set()):
                wrong.append(f"{rel} imports {name} ({own} -> {target})")
            top = name.split(".")[0]
            if top in THIRD_PARTY_HOMES and own not in THIRD_PARTY_HOMES[top]:
                wrong.append(f"{rel} imports {name}, which belongs in {THIRD_PARTY_HOMES[top]}")
    assert wrong == []


def test_the_architecture_note_names_every_module():
    """ARCHITECTURE.md lists every module of the tree under its layer, and nothing that is gone."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    note = (root / "ARCHITECTURE.md").read_text(encoding="utf-8")
    named = set(re.findall(r"`(stw_tui/[\w/]+\.py|backends/[\w/]+\.py)`", note))
    present = {p.relative_to(root).as_posix() for p in [*(root / "stw_tui").rglob("*.py"),
                                                        *(root / "backends").rglob("*.py")]
               if p.name not in ("__init__.py", "__main__.py")}
    assert named - present == set(), "named in ARCHITECTURE.md but gone"
    assert present - named == set(), "in the tree but not in ARCHITECTURE.md"


def _backend_modules() -> dict:
    """Dotted module name -> file, for every module of the backend packages (stw_scipy.dense …)."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent / "backends"
    paths = {}
    for path in root.rglob("*.py"):
        rel = path.relative_to(root).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        paths[".".join(parts)] = path
    return paths


def test_no_import_cycle_of_any_length():
    """No chain of imports leads from a module back to itself, in the core or the backends (the
    torch backend's batch and backend modules once imported each other), counting imports inside
    functions and under TYPE_CHECKING: every module has a place above all it imports
    (ARCHITECTURE.md)."""
    paths = {**_core_modules(), **_backend_modules()}
    assert "stw_torch.batch" in paths and "stw_scipy.dense" in paths
    packages = {name for name, path in paths.items() if path.name == "__init__.py"}
    edges = {}
    for name, path in paths.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        # `from stw_tui.session import autosave` names the module, not the package
        edges[name] = {m for m in _imports_of(path, package, set(paths), typing_too=True) if m != name and m not in packages}
    state, stack, cycles = {}, [], []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(edges[node]):
            if state.get(nxt) == "open":
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"

    for node in sorted(edges):
        if node not in state:
            visit(node)
    assert cycles == []
