from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SESSIONS = ROOT / "sessions"


@pytest.fixture
def session():
    from stw_tui.session import Session

    return Session()


def run_lines(session, text: str):
    """Execute a block of session text on ``session`` and return it."""
    session.run_text(text)
    return session
