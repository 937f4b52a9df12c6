"""The symbolic compiler: values and derivatives against independent evaluations."""

import numpy as np
import pytest
import sympy as sp

from stw_tui.sym.compiler import compile_term
from stw_tui.sym.symbols import TIME, dof_symbol, named_symbol

x, xd, xdd = (dof_symbol("x", k) for k in range(3))
y = dof_symbol("y")
g = named_symbol("g")

EXPRS = [
    sp.sin(x) * y**2 + g * xd * TIME,
    sp.Abs(xdd - 1) + sp.Max(x, y) ** 2 + sp.Min(xd, 2) + sp.sign(y),
    sp.atan2(y, x) * sp.exp(-xd**2) + sp.sqrt(1 + x**2),
]


@pytest.mark.parametrize("expr", EXPRS, ids=["smooth", "kinks", "atan2"])
def test_gradient_and_hessian_match_sympy(expr):
    term = compile_term(expr, {"x", "y"}, {"g"})
    rng = np.random.default_rng(0)
    n = 50
    values = rng.uniform(0.1, 1.7, size=(n, term.k))   # away from the kinks of abs/min/max/sign
    values[:, [i for i, v in enumerate(term.variables) if v.dof == "y"]] += 2.0  # y > x: Max picks y
    times = rng.uniform(0, 1, n)
    f, grad, hess = term.full(values, times, np.array([9.81]) if term.parameters else np.zeros(0))
    symbols = [dof_symbol(v.dof, v.order) for v in term.variables]
    subs_base = {g: 9.81}
    for i in range(0, n, 7):
        subs = {**subs_base, TIME: times[i], **dict(zip(symbols, values[i]))}
        assert f[i] == pytest.approx(float(expr.subs(subs)), rel=1e-12, abs=1e-12)
        for a, sa in enumerate(symbols):
            assert grad[i, a] == pytest.approx(float(sp.diff(expr, sa).subs(subs)), rel=1e-10, abs=1e-10)
        for p, (a, b) in enumerate(term.hessian_pairs):
            exact = float(sp.diff(expr, symbols[a], symbols[b]).subs(subs))
            assert hess[i, p] == pytest.approx(exact, rel=1e-9, abs=1e-9)


def test_terms_are_cached_by_expression_and_constants_are_parameters():
    a = compile_term(g * x, {"x"}, {"g"})
    b = compile_term(g * x, {"x"}, {"g"})
    assert a is b
    # Changing g's value needs no recompilation: it is an argument.
    one = a.value(np.array([[2.0]]), np.array([0.0]), np.array([1.0]))
    three = a.value(np.array([[2.0]]), np.array([0.0]), np.array([3.0]))
    assert (one[0], three[0]) == (2.0, 6.0)


def test_waypoints_that_differ_only_in_their_number_share_one_compiled_term():
    # `x = 0.25`, `x = -1.5` (g*x - 0.7 with a constant too): one skeleton, x + __lit0, compiled
    # once; each term keeps its own expression and number, and computes bitwise what a term
    # compiled with the number inlined computes (one addition, the same in either order).
    from stw_tui.sym import compiler

    rng = np.random.default_rng(3)
    values, times = rng.normal(size=(40, 1)), rng.uniform(0, 1, 40)
    terms = [compile_term(x - c, {"x"}, set()) for c in (0.25, -1.5, 3.0e-7)]
    assert len({id(t.core) for t in terms}) == 1 and len({id(t) for t in terms}) == 3
    for term, c in zip(terms, (0.25, -1.5, 3.0e-7)):
        assert term.expr == x - c and term.parameters == () and list(term.literals) == [-c]
        inlined = compiler._compile(x - c, term.variables, ())
        for mine, theirs in zip(term.full(values, times, np.zeros(0)), inlined.full(values, times, np.zeros(0))):
            assert np.array_equal(mine, theirs)
        assert np.array_equal(term.value(values, times, np.zeros(0)), values[:, 0] - c)
    scaled = compile_term(g * x - 0.7, {"x"}, {"g"})
    assert scaled.parameters == ("g",)
    assert scaled.value(values[:3], times[:3], np.array([2.0])).tolist() == (2.0 * values[:3, 0] - 0.7).tolist()
    # Numbers elsewhere stay inlined (reordering a longer sum or a product would change its last
    # bits): a coefficient, an exponent, a three-term sum.
    for expr in (0.5 * x, x ** 1.5, x + y - 0.25, x - 0.25 * y):
        assert not isinstance(compile_term(expr, {"x", "y"}, set()), compiler.LiteralTerm)


def test_a_sign_that_symengine_writes_itself_compiles():
    # symengine turns atan2(y, y) into pi/4 + pi/2 (sign(y) - 1); it could not compile that
    # sign's derivative ("Not Implemented", an internal error in the console)
    term = compile_term(sp.atan2(y, y) * x, {"x", "y"}, set())
    values = np.array([[2.0, 0.5], [3.0, -1.5]])             # (x, y) at two instances
    value, grad, hess = term.full(values, np.zeros(2), np.zeros(0))
    assert value.tolist() == pytest.approx([2.0 * np.pi / 4, 3.0 * -3 * np.pi / 4], rel=1e-15)
    assert np.allclose(grad, [[np.pi / 4, 0.0], [-3 * np.pi / 4, 0.0]], rtol=1e-15, atol=0.0)


def _random_term(rng, depth: int) -> sp.Expr:
    """A random expression of DOF values and derivatives, a constant, time and numbers (seeded)."""
    def number():
        return rng.choice([sp.Float(round(rng.uniform(-3, 3), 3)), sp.Integer(rng.randint(-3, 3)),
                           sp.Rational(1, 3), sp.pi])
    if depth == 0 or rng.random() < 0.25:
        return rng.choice([x, xd, xdd, y, g, TIME]) if rng.random() < 0.75 else number()
    a, b = _random_term(rng, depth - 1), _random_term(rng, depth - 1)
    return rng.choice([lambda: a + b, lambda: a - b, lambda: a * b, lambda: a / (b * b + 1),
                       lambda: sp.sin(a), lambda: sp.cos(b), lambda: a ** rng.choice([2, 3, -1]),
                       lambda: sp.tanh(a) * number(), lambda: a - number(), lambda: number() * a + number(),
                       lambda: sp.exp(-a * a), lambda: sp.atan2(a, b), lambda: sp.sqrt(a * a + 1),
                       lambda: sp.Abs(a), lambda: sp.Max(a, b), lambda: sp.Min(a, number()),
                       lambda: sp.log(a * a + 1), lambda: sp.sign(a) * b * b])()


def test_random_terms_compute_what_sympy_computes():
    """Seeded random terms of every function, literals in every place: the compiled values (and,
    without kinks, gradients) equal sympy's own lambdified expression and derivatives to 1e-9.
    A random run found atan2(y, y), which symengine writes with a sign it cannot compile."""
    import random

    rng, points, compared = random.Random(5), np.random.default_rng(5), 0
    with np.errstate(all="ignore"):         # sympy's numpy code outside a domain
        for _ in range(60):
            expr = _random_term(rng, 4)
            if not expr.free_symbols & {x, xd, xdd, y}:
                continue
            term = compile_term(expr, {"x", "y"}, {"g"})
            symbols = [dof_symbol(v.dof, v.order) for v in term.variables]
            values, times = points.uniform(-2, 2, (31, term.k)), points.uniform(0.01, 1, 31)
            f, grad, _ = term.full(values, times, np.array([1.3] if term.parameters else []))
            columns = [values[:, i] for i in range(term.k)] + [times, np.full(31, 1.3)]
            want = sp.lambdify(symbols + [TIME, g], expr, "numpy")(*columns)
            want = np.broadcast_to(np.asarray(want, float), (31,))
            finite = np.isfinite(want)
            assert np.array_equal(np.isfinite(f), finite), expr
            scale = max(1.0, np.abs(want[finite]).max(initial=0.0))
            assert np.abs(f[finite] - want[finite]).max(initial=0.0) <= 1e-9 * scale, expr
            if not expr.has(sp.Abs, sp.Max, sp.Min, sp.sign):
                for i, symbol in enumerate(symbols):
                    slope = sp.lambdify(symbols + [TIME, g], sp.diff(expr, symbol), "numpy")(*columns)
                    slope = np.broadcast_to(np.asarray(slope, float), (31,))
                    both = np.isfinite(slope) & np.isfinite(grad[:, i])
                    scale = max(1.0, np.abs(slope[both]).max(initial=0.0))
                    assert np.abs(grad[both, i] - slope[both]).max(initial=0.0) <= 1e-8 * scale, expr
            compared += 1
    assert compared >= 40


def test_an_undefined_symbol_is_a_clear_error():
    from stw_tui.sym.errors import StwError

    with pytest.raises(StwError, match="'q' is not defined"):
        compile_term(named_symbol("q") * x, {"x"}, set())


def test_compiled_terms_are_kept_on_disk_across_runs(tmp_path, monkeypatch):
    from stw_tui.sym import compiler

    monkeypatch.setenv("STW_CACHE_DIR", str(tmp_path))
    expr = sp.cos(x) * xd**2 + g * y
    monkeypatch.setattr(compiler, "_CACHE", {})
    first = compile_term(expr, {"x", "y"}, {"g"})
    assert len(list(tmp_path.glob("*.pkl"))) == 1
    real_compile = compiler._compile
    monkeypatch.setattr(compiler, "_CACHE", {})            # a new run: nothing in memory
    monkeypatch.setattr(compiler, "_compile", lambda *a: pytest.fail("compiled again"))
    second = compile_term(expr, {"x", "y"}, {"g"})
    values, times = np.array([[0.3, 1.2, 2.0]]), np.array([0.5])
    for a, b in zip(first.full(values, times, np.array([9.81])), second.full(values, times, np.array([9.81]))):
        assert np.array_equal(a, b)
    # A damaged entry is compiled afresh (and rewritten), not trusted.
    next(tmp_path.glob("*.pkl")).write_bytes(b"garbage")
    monkeypatch.setattr(compiler, "_CACHE", {})
    monkeypatch.setattr(compiler, "_compile", real_compile)
    with pytest.warns(RuntimeWarning, match="ignored a term cache entry"):   # the user is told
        third = compile_term(expr, {"x", "y"}, {"g"})
    assert np.array_equal(third.value(values, times, np.array([9.81])), first.value(values, times, np.array([9.81])))
    assert next(tmp_path.glob("*.pkl")).read_bytes() != b"garbage"


def test_the_order_sympy_keeps_a_sums_terms_in_does_not_change_the_compiled_numbers(monkeypatch):
    # basketball's arm tip height: after `stw bench` had compiled other sessions, sympy held two
    # of its terms in the other order; symengine's code summed them in that order, and the solve
    # took 95 iterations instead of 120 to another local optimum
    from stw_tui.sym import compiler

    monkeypatch.setenv("STW_CACHE_DIR", "off")
    e, s_, w, by = sp.symbols("ELBOW SHOULDER WRIST BY")
    first = -0.15 * (-sp.sin(e) * sp.sin(s_) + sp.cos(e) * sp.cos(s_)) * sp.sin(w)
    second = -0.15 * (sp.sin(e) * sp.cos(s_) + sp.sin(s_) * sp.cos(e)) * sp.cos(w)
    rest = [by, -0.35 * sp.sin(s_), -0.3 * sp.sin(s_) * sp.cos(e), -0.3 * sp.sin(e) * sp.cos(s_)]
    orders = [sp.Add(*rest[:2], first, second, *rest[2:], evaluate=False),
              sp.Add(*rest[:2], second, first, *rest[2:], evaluate=False)]
    assert orders[0].args != orders[1].args
    values = np.random.default_rng(6).standard_normal((4, 2000))
    got = []
    for expr in orders:
        monkeypatch.setattr(compiler, "_CACHE", {})
        term = compile_term(expr, {"BY", "ELBOW", "SHOULDER", "WRIST"}, set())
        got.append(np.asarray(term.full(values, np.zeros(2000), np.zeros(0))[0]))
    assert np.array_equal(got[0], got[1])


def test_literals_that_print_alike_are_kept_apart_on_disk(tmp_path, monkeypatch):
    # symengine prints 0.1 + 0.2 (0.30000000000000004) as 0.3: under the printed text alone a
    # second run took the first term's compiled code, literal included, for the other term
    from stw_tui.sym import compiler

    monkeypatch.setenv("STW_CACHE_DIR", str(tmp_path))
    near, exact = sp.Float(0.1 + 0.2), sp.Float(0.3)
    for literal in (near, exact):                          # each compiled once, in a fresh run
        monkeypatch.setattr(compiler, "_CACHE", {})
        compile_term(literal * sp.sin(x) * y, {"x", "y"}, set())
    assert len(list(tmp_path.glob("*.pkl"))) == 2
    values, times = np.array([[1.0], [1.0]]), np.array([0.0])
    for literal in (near, exact):                          # a later run reads each one back
        monkeypatch.setattr(compiler, "_CACHE", {})
        monkeypatch.setattr(compiler, "_compile", lambda *a: pytest.fail("compiled again"))
        term = compile_term(literal * sp.sin(x) * y, {"x", "y"}, set())
        assert term.value(values, times, np.array([]))[0] == float(literal) * np.sin(1.0)


@pytest.mark.parametrize("line", ["print sin(atan(tan(0) ^ x))", "objective z: 0^x"])
def test_an_expression_whose_derivative_is_infinite_is_refused_clearly(line):
    # 0^x differentiates to 0^x·log(0): symengine cannot compile the complex infinity and raised
    # a RuntimeError, which reached the console as an "internal error" (found by the 100k fuzz).
    from stw_tui.session.session import Session
    from stw_tui.sym.errors import StwError

    s = Session()
    s.run_text("time 0 1 knots=8\ndof x = t\n")
    with pytest.raises(StwError, match="infinite everywhere"):
        s.execute(line)
    assert not s.scene.objectives


# --- size checks: counted without remembering leaves, against a plain count of the tree --------

def _nodes(expr) -> int:
    """Every node of ``expr`` as a tree, repeats included (an independent count)."""
    return sum(1 for _ in sp.preorder_traversal(expr))


SIZED = [
    x,
    sp.Float(0.25) * x + sp.Float(0.25) * y + sp.Float(0.5) * x * y,  # the same Float, twice
    sp.sin(x + 1) ** 2 + sp.cos(x + 1) ** 2 * sp.sin(x + 1),         # shared subtrees
    sp.Piecewise((x**2, x > 0), (-x, True)) + sp.atan2(y, sp.Float(1.5) * x),
]


@pytest.mark.parametrize("expr", SIZED, ids=["symbol", "floats", "shared", "piecewise"])
def test_tree_size_counts_every_node_as_the_tree_holds_it(expr):
    from stw_tui.sym import compiler

    assert compiler._tree_size(expr, lambda s: 1) == _nodes(expr)


def test_expanded_size_is_the_size_of_the_substituted_tree():
    from stw_tui.sym import compiler

    a, b = named_symbol("a"), named_symbol("b")
    definitions = {a: sp.sin(x) + sp.Float(0.5) * y, b: a * a + sp.cos(a) * sp.Float(0.5)}
    expr = b + a * sp.Float(2.5) + x

    def substituted(e) -> int:   # the tree with each defined symbol replaced, unevaluated
        if e in definitions:
            return substituted(definitions[e])
        return 1 + sum(substituted(arg) for arg in e.args)
    assert compiler.expanded_size(expr, definitions) == substituted(expr) == 28


def _distinct(expr) -> int:
    """Each distinct compound node of ``expr`` once, with the leaves under it (an independent
    count: a recursive walk with a set)."""
    seen = set()

    def walk(e):
        if e in seen:
            return 0
        seen.add(e)
        return 1 + sum(walk(a) if a.args else 1 for a in e.args)
    return walk(expr)


def test_the_size_check_refuses_one_node_over_the_limit_and_passes_at_it():
    from stw_tui.sym import compiler, limits
    from stw_tui.sym.errors import LimitError

    expr = SIZED[2]
    size = _distinct(expr)
    assert size < _nodes(expr)       # shared subtrees count once
    compiler._check_size(expr, size, 64)                   # at the limit: passes
    with pytest.raises(LimitError, match="expression_size"):
        compiler._check_size(expr, size - 1, 64)
    assert limits.value_or_ceiling("expression_size") > size


AFFINE = [(x - 0.25, True), (xd, True), (2 * x - 3 * y + TIME, True),
          (sp.sin(TIME) * x + g * xd + sp.cos(TIME), True), (x * (1 + x) - x**2, True),
          (x * y, False), (sp.sin(x), False), (sp.sign(x), False), (sp.Abs(x), False),
          (sp.Max(x, 0), False), (x**2, False)]


@pytest.mark.parametrize("expr,affine", AFFINE, ids=[str(e) for e, _ in AFFINE])
def test_affine_terms_are_told_from_the_others(expr, affine):
    # sign(x) has a zero gradient and no Hessian, and is not affine; x(1 + x) - x² is, once
    # symengine has collected it. An affine term's value is its gradient's terms plus its value
    # at zero, at any point.
    term = compile_term(expr, {"x", "y"}, {"g"})
    assert term.affine is affine
    if affine:
        rng = np.random.default_rng(1)
        values, times, params = rng.normal(size=(20, term.k)), rng.uniform(0, 1, 20), np.array([9.81][:len(term.parameters)])
        f, grad, _ = term.full(values, times, params)
        f0 = term.value(np.zeros_like(values), times, params)
        assert np.allclose(f, (grad * values).sum(1) + f0, rtol=1e-14, atol=1e-14)


def test_the_affine_flag_is_kept_on_disk_and_shared_by_waypoints(tmp_path, monkeypatch):
    from stw_tui.sym import compiler

    monkeypatch.setenv("STW_CACHE_DIR", str(tmp_path))
    for expr, affine in ((x - 0.75, True), (x * y, False)):
        monkeypatch.setattr(compiler, "_CACHE", {})
        assert compile_term(expr, {"x", "y"}, set()).affine is affine
        monkeypatch.setattr(compiler, "_CACHE", {})            # a new run: read from disk
        assert compile_term(expr, {"x", "y"}, set()).affine is affine
    # an entry in the layout before the flag (another name) is neither read nor overwritten
    assert all(compiler.TERM_ENTRY not in p.name for p in tmp_path.glob("*.pkl"))
