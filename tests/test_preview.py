"""Preview, then accept: under `set preview on` a solve proposes, `accept` takes the proposal
exactly (as if preview were off), `reject` leaves the scene bit for bit, and the journal replays
the same decisions."""

import numpy as np
import pytest

import catalogue
from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError

SCENE = catalogue.problem("analytic_landing").text


def test_preview_proposes_and_accept_gives_the_solve_without_preview():
    plain = run_lines(Session(), SCENE + "iterate 30\n")
    s = run_lines(Session(), SCENE + "set preview on\n")
    before = s.scene.coefficient_vector().copy()
    outcome = s.execute("iterate 30")
    assert np.array_equal(s.scene.coefficient_vector(), before)        # the scene is unchanged
    assert "proposal: objective" in outcome.message and "now:      objective" in outcome.message
    s.execute("accept")
    assert np.array_equal(s.scene.coefficient_vector(), plain.scene.coefficient_vector())
    # The warm start came with it: the next solve (preview off) matches the plain session's.
    s.execute("set preview off")
    plain.execute("set preview off")
    s.execute("iterate 3")
    plain.execute("iterate 3")
    assert np.array_equal(s.scene.coefficient_vector(), plain.scene.coefficient_vector())
    s.execute("undo")
    s.execute("undo")
    s.execute("undo")   # iterate 3, set preview off, accept
    assert np.array_equal(s.scene.coefficient_vector(), before)


def test_reject_keeps_the_scene_and_the_journal_replays_the_decisions():
    s = run_lines(Session(), SCENE + "set preview on\n")
    before = s.scene.coefficient_vector().copy()
    s.execute("iterate 30")
    s.execute("reject")
    assert np.array_equal(s.scene.coefficient_vector(), before) and s.proposal is None
    with pytest.raises(StwError, match="nothing to accept"):
        s.execute("accept")
    s.execute("iterate 30")
    s.execute("dof x knots=10")            # changes the scene: the proposal is dropped
    assert s.proposal is None
    s.execute("iterate 30")
    s.execute("accept")
    replay = run_lines(Session(), "\n".join(s.journal.replayable()) + "\n")
    assert np.array_equal(replay.scene.coefficient_vector(), s.scene.coefficient_vector())
