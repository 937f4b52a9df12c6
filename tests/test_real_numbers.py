"""sign, abs, min and max of a value that is not a real number are refused as such, never read as
a number (issue 54, item 9): the compiled sign made NaN a 0, and max(NaN, y) read y."""

import pytest

from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError


@pytest.fixture
def session():
    session = Session()
    session.run_text("time 0 1 knots=4\ndof y\nconst c0 = 0.1\n")
    return session


@pytest.mark.parametrize("expr", ["sign(log(-c0))", "sign(acos(2*t))", "abs(acos(2*t))", "max(acos(2*t), y)",
                                  "max(y, acos(2*t))", "min(acos(2*t), y + 1)", "min(y - 1, log(-c0))",
                                  "max(y, t, acos(2*t))"])
def test_a_function_of_a_non_real_value_is_not_a_real_number(session, expr):
    with pytest.raises(StwError, match="is not a real number"):
        session.execute(f"print {expr}")


def test_real_values_keep_their_sign_min_and_max(session):
    assert "min -1, max 1, mean 0," in session.execute("print sign(t - 0.5)").message
    assert "start 0, end 0" in session.execute("print sign(y)").message
    assert "min 0, max 1" in session.execute("print max(y, t)").message
    assert "min -1, max 0" in session.execute("print min(y, t - 1)").message
