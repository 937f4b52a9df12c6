"""Throttle and ThrottledCall on a fake clock and a fake timer: no sleeping, nothing timed."""

import pytest

from stw_tui.session.throttle import Throttle, ThrottledCall


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class FakeTimers:
    """``schedule(delay, callback)`` as Textual's set_timer: fires when the test says so."""

    def __init__(self, clock: FakeClock):
        self.clock = clock
        self.waiting: list[list] = []   # [due time, callback, stopped]

    def __call__(self, delay, callback):
        timer = [self.clock.now + delay, callback, False]
        self.waiting.append(timer)

        class Handle:
            def stop(self):
                timer[2] = True
        return Handle()

    def advance(self, seconds: float) -> None:
        """Move the clock on, firing the timers that fall due on the way, in order."""
        end = self.clock.now + seconds
        while True:
            due = sorted((t for t in self.waiting if not t[2] and t[0] <= end), key=lambda t: t[0])
            if not due:
                break
            timer = due[0]
            self.waiting.remove(timer)
            self.clock.now = timer[0]
            timer[1]()
        self.clock.now = end


def test_throttle_is_due_at_once_then_once_per_interval():
    clock = FakeClock()
    throttle = Throttle(2.0, clock)
    assert throttle.wait() == 0 and throttle.due()         # never acted: due at once
    assert throttle.wait() == 2.0 and not throttle.due()   # just acted
    clock.now += 1.5
    assert throttle.wait() == 0.5 and not throttle.due()   # a refused act is not counted
    clock.now += 0.5
    assert throttle.due()                                   # exactly one interval later
    clock.now += 0.1
    throttle.reset()
    assert throttle.due()


def test_throttle_marked_at_the_start_is_first_due_one_interval_later():
    clock = FakeClock()
    throttle = Throttle(3.0, clock)
    throttle.mark()
    acted = []
    for second in range(10):
        if throttle.due():
            acted.append(second)
        clock.now += 1.0
    assert acted == [3, 6, 9]


def test_zero_interval_is_always_due():
    throttle = Throttle(0.0, FakeClock())
    assert all(throttle.due() for _ in range(5))


def test_throttled_call_runs_at_once_then_coalesces_requests_into_one_trailing_call():
    clock = FakeClock()
    timers = FakeTimers(clock)
    calls = []
    call = ThrottledCall(lambda: calls.append(clock.now), 0.5, timers, clock)

    call.request()                     # due: runs now
    assert calls == [100.0] and not call.pending
    clock.now += 0.125                 # (steps exact in binary: the times compare equal)
    for _ in range(4):                 # too soon: one call, when the interval has passed
        call.request()
        clock.now += 0.0625
    assert calls == [100.0] and call.pending and len(timers.waiting) == 1
    timers.advance(1.0)
    assert calls == [100.0, 100.5] and not call.pending
    call.request()                     # 0.875 s after the last call: due again
    assert calls == [100.0, 100.5, 101.375]


def test_cancel_drops_the_waiting_call_and_lets_the_next_run_at_once():
    clock = FakeClock()
    timers = FakeTimers(clock)
    calls = []
    call = ThrottledCall(lambda: calls.append(clock.now), 0.5, timers, clock)
    call.request()
    clock.now += 0.125
    call.request()
    assert call.pending
    call.cancel()
    assert not call.pending
    call.request()                     # 0.125 s after the last call, but cancel forgot it: runs now
    assert calls == [100.0, 100.125]
    timers.advance(1.0)                # the stopped timer never fires
    assert calls == [100.0, 100.125]



def test_a_deferred_call_comes_an_interval_after_the_deferral_but_never_past_twice_the_interval():
    """The TUI defers its next live redraw when a plot is switched to during a solve."""
    clock = FakeClock()
    timers = FakeTimers(clock)
    calls = []
    call = ThrottledCall(lambda: calls.append(clock.now), 0.5, timers, clock)
    call.request()                       # runs at once (100.0)
    clock.now += 0.2
    call.request()                       # due at 100.5
    clock.now += 0.2
    call.defer()                         # 100.4: now due at 100.9
    timers.advance(0.4)
    assert calls == [100.0] and call.pending
    timers.advance(0.1)
    assert calls == [100.0, 100.9] and not call.pending
    for _ in range(3):                   # deferred again and again: not past 100.9 + 1.0
        timers.advance(0.3)
        call.request()
        call.defer()
    assert len(calls) == 2
    timers.advance(0.2)
    assert calls[2:] == [pytest.approx(101.9)]
