"""tree_key: the text that names a compiled term on disk, read off the sympy tree.

The property that matters: two trees with one text compile to the same code. The compiler's
code is a function of the symengine expression it converts (compiler._to_symengine), so every
group of random trees sharing a text must share that expression's printed form and its exact
literals. The other direction is what makes the cache useful: a term is found again whatever
order sympy holds its terms in, in whatever process.
"""

from __future__ import annotations

import random

import sympy as sp

from stw_tui.sym import compiler
from stw_tui.sym.tree_key import tree_text

x, y, z = sp.symbols("x y z")


def test_the_order_of_a_sums_or_products_terms_does_not_change_the_text():
    a = sp.Add(x, sp.Mul(2, y, evaluate=False), sp.sin(z), evaluate=False)
    b = sp.Add(sp.sin(z), x, sp.Mul(y, 2, evaluate=False), evaluate=False)
    assert tree_text(a) == tree_text(b) is not None


def test_what_changes_the_code_changes_the_text():
    different = [
        (sp.Float(0.1) + sp.Float(0.2) + x, sp.Float(0.3) + x),           # 1 ulp apart, print alike
        (sp.Float("0.1", 53) * x, sp.Float("0.1", 80) * x),               # precision
        (sp.atan2(x, y), sp.atan2(y, x)),                                 # order of arguments
        (x ** y, y ** x),
        (x - y, y - x),
        (sp.Piecewise((x, y > 0), (z, True)), sp.Piecewise((x, y >= 0), (z, True))),
        (sp.Symbol("x") * 2, sp.Symbol("x_") * 2),
        (sp.Rational(1, 3) * x, sp.Rational(1, 4) * x),
        (sp.pi * x, sp.E * x),
    ]
    for a, b in different:
        assert tree_text(a) is not None and tree_text(b) is not None
        assert tree_text(a) != tree_text(b), (a, b)


def test_nodes_it_does_not_know_leave_the_term_to_the_symengine_text():
    assert tree_text(sp.Dummy("x") + y) is None           # two dummies may share a name
    assert tree_text(sp.Function("f")(x) + y) is None
    a, b = sp.symbols("a b", commutative=False)
    assert tree_text(a * b) is None                        # a product whose order matters


def _random_tree(rng: random.Random, depth: int) -> sp.Expr:
    leaves = [x, y, z, sp.Integer(2), sp.Rational(1, 2), sp.Float(0.1), sp.Float(0.3), sp.pi]
    if depth == 0 or rng.random() < 0.25:
        return rng.choice(leaves)
    kind = rng.randrange(6)
    a, b = _random_tree(rng, depth - 1), _random_tree(rng, depth - 1)
    if kind == 0:
        return a + b
    if kind == 1:
        return a * b
    if kind == 2:
        return a - b
    if kind == 3:
        return sp.sin(a) * sp.cos(b)
    if kind == 4:
        return sp.atan2(a, b)
    return sp.Piecewise((a, rng.choice([x, y, z]) > 0), (b, True))   # (conditions on a tree can
                                                                      # fold into ITE, which symengine cannot read)


def test_random_trees_that_share_a_text_convert_to_one_symengine_expression():
    rng = random.Random(4)
    groups: dict[str, set[str]] = {}
    for _ in range(1500):
        tree = _random_tree(rng, 4)
        text = tree_text(tree)
        assert text is not None
        e = compiler._to_symengine(tree)
        groups.setdefault(text, set()).add(compiler._term_key(e, (), ()))
    assert all(len(keys) == 1 for keys in groups.values())
    assert len(groups) > 500   # the trees were varied enough to test something


def test_a_cached_term_is_found_without_converting_it_to_symengine(tmp_path, monkeypatch):
    monkeypatch.setenv("STW_CACHE_DIR", str(tmp_path))
    expr = sp.sin(sp.Symbol("A")) * sp.Symbol("g") + sp.Float(0.25)
    first = compiler._build(expr, (), ("A", "g"))
    monkeypatch.setattr(compiler, "_to_symengine", lambda e: (_ for _ in ()).throw(AssertionError("converted")))
    again = compiler._build(expr, (), ("A", "g"))
    assert again.cache_key == first.cache_key
