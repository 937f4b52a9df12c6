"""The TUI's heap settling (stw_tui/app/heap.py): what survives a command is frozen, garbage is
not, and a frozen cycle that becomes garbage is reclaimed once the frozen heap has regrown."""

import gc
import weakref

import pytest

from stw_tui.app.heap import HeapSettler


class Node:
    """A cycle's member (it refers to itself) that a weak reference can watch."""

    def __init__(self):
        self.me = self


def _tracked_ids() -> set[int]:
    """The objects a collection walks (frozen ones are in no generation)."""
    return {id(o) for o in gc.get_objects()}


@pytest.fixture
def thawed():
    """Leave the test runner's heap unfrozen, as it was."""
    gc.unfreeze()
    yield
    gc.unfreeze()


def test_garbage_is_collected_and_what_survives_is_frozen(thawed):
    settler = HeapSettler()
    garbage = Node()
    dead = weakref.ref(garbage)
    del garbage                      # an unreachable cycle: only a collection reclaims it
    kept = Node()
    settler.settle()                 # the first settle is a full one
    assert dead() is None
    first = gc.get_freeze_count()
    assert settler.full_at == first > 0
    new = [Node() for _ in range(100)]
    tracked = _tracked_ids()
    assert id(kept) not in tracked and id(new[0]) in tracked   # frozen; made since: walked
    garbage = Node()
    dead = weakref.ref(garbage)
    del garbage
    settler.settle()                 # not a full one: the frozen part grew by far less than itself
    assert dead() is None            # young garbage is collected all the same
    assert id(new[0]) not in _tracked_ids()
    assert settler.full_at == first


def test_a_frozen_cycle_that_became_garbage_is_reclaimed_once_the_frozen_heap_has_regrown(thawed):
    settler = HeapSettler(regrowth=0.01)
    held = [Node()]
    dead = weakref.ref(held[0])
    settler.settle()
    base = settler.full_at
    held.clear()                     # frozen while alive, garbage now: no collection sees it
    gc.collect()
    settler.settle()                 # the frozen heap has not grown by 1%: it stays
    assert dead() is not None and settler.full_at == base
    grown = [[] for _ in range(int(0.02 * base) + 10)]
    settler.settle()                 # now it has: the whole heap is collected again
    assert dead() is None
    assert settler.full_at >= base + len(grown)


def test_stw_s_own_app_settles_its_heap_after_each_command_and_a_test_s_app_does_not(thawed):
    import asyncio

    import test_app_support as support
    from stw_tui.app import create_app

    def frozen_after_a_command(**options) -> int:
        app = create_app(solver_process=False, **options)

        async def scenario():
            async with app.run_test() as pilot:
                await support.settle(pilot)
                gc.unfreeze()
                await support.submit(pilot, "dof x")
                await support.settle(pilot)
                app.runner.thread.join(timeout=10)   # the worker settles after posting its result
                return gc.get_freeze_count()

        return asyncio.run(scenario())

    assert frozen_after_a_command(settle_heap=True) > 0
    assert frozen_after_a_command() == 0
