"""A cluster runs code in stw (its results come back pickled), so only the user chooses one
(issue 54, item 1): `set scheduler ADDRESS` from a session file or a journal being replayed is
refused unless the address is named outside it; an address that is not a Dask scheduler, or a
tls:// one without Dask's TLS files, gives a clear error, not an internal one."""

import socket
import threading

import pytest
import catalogue

from stw_tui.session.session import Session
from stw_tui.session.survey import base_text
from stw_tui.sym.errors import StwError

pytest.importorskip("distributed")

PENDULUM = catalogue.problem("analytic_pendulum_swing_up").text
REMOTE = "tcp://10.0.0.5:8786"


def test_a_session_file_may_not_choose_a_cluster(monkeypatch, tmp_path):
    monkeypatch.delenv("STW_SCHEDULER", raising=False)
    with pytest.raises(StwError, match=r"line 1: a session file may not send surveys .*STW_SCHEDULER=tcp://10.0.0.5:8786"):
        Session().run_text(f"set scheduler {REMOTE}\n")
    path = tmp_path / "hostile.stw"
    path.write_text(f"# harmless\nset scheduler {REMOTE}\n")
    session = Session()
    with pytest.raises(StwError, match="may not send surveys"):
        session.execute(f"open {path}")
    assert session.scene.scheduler == ""
    session.run_text("set scheduler serial\nset scheduler local\n")   # this machine: no trust needed
    session.execute(f"set scheduler {REMOTE}")                       # typed: the user chose it
    assert session.scene.scheduler == REMOTE


def test_a_cluster_named_outside_the_file_may_be_replayed(monkeypatch):
    monkeypatch.setenv("STW_SCHEDULER", f"tcp://127.0.0.1:1,{REMOTE}")
    session = Session()
    session.run_text(f"set scheduler {REMOTE}\n")
    assert session.scene.scheduler == REMOTE
    monkeypatch.delenv("STW_SCHEDULER")
    session = Session()
    session.trusted_schedulers.add(REMOTE)   # `stw survey --scheduler ADDR`
    session.run_text(f"set scheduler {REMOTE}\n")
    # a worker replays the journal without the address (and the step stays a step for `undo`)
    assert base_text(session) == "set scheduler local"


@pytest.fixture
def not_dask():
    """A TCP service on loopback that answers every connection with 8 bytes a Dask reader takes
    for the length of an exabyte message."""
    server = socket.create_server(("127.0.0.1", 0))

    def serve():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                try:
                    conn.sendall(b"\xff" * 8 + b"HTTP/1.0 200 OK\r\n\r\n")
                    conn.recv(1024)
                except OSError:
                    pass

    threading.Thread(target=serve, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    server.close()


def test_a_service_that_is_not_dask_is_a_clear_error(not_dask):
    session = Session()
    session.run_text(PENDULUM)
    session.execute(f"set scheduler {not_dask}")
    with pytest.raises(StwError) as info:
        session.execute("survey 2 iterate=2")
    assert f"{not_dask} is not a Dask scheduler" in str(info.value)
    assert "internal error" not in str(info.value)


def test_tls_without_dask_tls_files_is_a_clear_error():
    session = Session()
    session.run_text(PENDULUM)
    session.execute("set scheduler tls://127.0.0.1:8786")
    with pytest.raises(StwError, match="is a TLS address: set Dask's TLS files") as info:
        session.execute("survey 2 iterate=2")
    assert "internal error" not in str(info.value)


def test_a_real_scheduler_passes_the_greeting_check():
    import asyncio

    from distributed import Scheduler

    from stw_tui.session.survey_engines import check_scheduler

    async def greet():
        async with Scheduler(port=0, host="127.0.0.1", dashboard_address=":0") as scheduler:
            await asyncio.get_running_loop().run_in_executor(None, check_scheduler, scheduler.address)

    asyncio.run(greet())
