

# --- a cache that cannot run code -------------------------------------------------------------

PLANTED = b"cos\nsystem\n(S'touch PWNED'\ntR."   # a pickle that runs a shell command when loaded


@pytest.fixture
def cache(tmp_path, monkeypatch):
    from stw_tui import compiler

    root = tmp_path / "terms"
    monkeypatch.setenv("STW_CACHE_DIR", str(root))
    monkeypatch.setattr(compiler, "_CACHE", {})
    monkeypatch.setattr(compiler, "_WARNED", set())
    monkeypatch.chdir(tmp_path)
    return root


def _compile_once():
    import sympy as sp

    from stw_tui.compiler import compile_term
    from stw_tui.symbols import dof_symbol

    return compile_term(sp.sin(dof_symbol("x")) * 3, {"x"}, set())


def _plant_everywhere(root):
    for entry in root.glob("*.pkl"):
        entry.write_bytes(PLANTED)


def test_a_new_cache_is_private_and_its_entries_are_signed(cache):
    import os
    import stat

    _compile_once()
    assert stat.S_IMODE(os.stat(cache).st_mode) == 0o700
    assert stat.S_IMODE(os.stat(cache / ".key").st_mode) == 0o600
    (entry,) = cache.glob("*.pkl")
    assert stat.S_IMODE(os.stat(entry).st_mode) == 0o600


def test_a_planted_entry_is_never_unpickled_but_recompiled_and_reported_once(cache, monkeypatch):
    from stw_tui import compiler

    _compile_once()
    _plant_everywhere(cache)
    monkeypatch.setattr(compiler, "_CACHE", {})
    with pytest.warns(RuntimeWarning, match="did not write"):
        term = _compile_once()
    assert not (cache.parent / "PWNED").exists()
    assert term.value([[0.5]], [0.0], []) == pytest.approx([3 * 0.479425538604203])
    monkeypatch.setattr(compiler, "_CACHE", {})
    _plant_everywhere(cache)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # reported once, not at every entry
        _compile_once()
    assert not (cache.parent / "PWNED").exists()


@pytest.mark.parametrize("mode", [0o770, 0o777, 0o755 | 0o002])
def test_a_cache_others_can_write_is_not_used(cache, monkeypatch, mode):
    import os

    from stw_tui import compiler

    _compile_once()
    _plant_everywhere(cache)
    os.chmod(cache, mode)
    monkeypatch.setattr(compiler, "_CACHE", {})
    with pytest.warns(RuntimeWarning, match="only you can write"):
        _compile_once()
    assert not (cache.parent / "PWNED").exists()


def test_a_key_others_can_read_disables_the_cache(cache, monkeypatch):
    import os

    from stw_tui import compiler

    _compile_once()
    os.chmod(cache / ".key", 0o644)
    monkeypatch.setattr(compiler, "_CACHE", {})
    monkeypatch.setattr(compiler, "_load", lambda *a: pytest.fail("read an entry"))
    with pytest.warns(RuntimeWarning, match="only you can read"):
        _compile_once()


def test_compiled_terms_in_memory_are_bounded(monkeypatch):
    import sympy as sp

    from stw_tui import compiler
    from stw_tui.symbols import dof_symbol

    monkeypatch.setenv("STW_CACHE_DIR", "off")
    monkeypatch.setattr(compiler, "_CACHE", {})
    monkeypatch.setattr(compiler, "MAX_TERMS", 5)
    x = dof_symbol("x")
    first = compiler.compile_term(x + 1, {"x"}, set())
    for k in range(2, 9):
        compiler.compile_term(x + k, {"x"}, set())
        compiler.compile_term(x + 1, {"x"}, set())     # used again: stays
    assert compiler.cache_size() == 5
    assert compiler.compile_term(x + 1, {"x"}, set()) is first
    assert compiler.compile_term(x + 2, {"x"}, set()) is not None
