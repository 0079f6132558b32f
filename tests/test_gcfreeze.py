"""The start-up's objects leave the cyclic collector's walk (ubf_async.runtime.gcfreeze), and
what the run allocates afterwards is still collected."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from ubf_async.runtime.gcfreeze import freeze_startup_objects


class Node:
    def __init__(self) -> None:
        self.peer: Node | None = None


@pytest.fixture
def unfrozen() -> Iterator[None]:
    gc.unfreeze()
    yield
    gc.unfreeze()


def cycle() -> weakref.ref[Node]:
    a, b = Node(), Node()
    a.peer, b.peer = b, a
    return weakref.ref(a)


def test_start_up_objects_are_frozen_and_later_cycles_still_collected(unfrozen: None) -> None:
    kept = [Node() for _ in range(1000)]  # start-up objects: alive when it is called
    garbage = cycle()  # start-up garbage: collected first, not frozen
    frozen = freeze_startup_objects()
    assert garbage() is None
    assert frozen == gc.get_freeze_count() and frozen >= len(kept)
    tracked = {id(o) for o in gc.get_objects()}
    assert not any(id(node) in tracked for node in kept)  # out of every generation's walk
    later = cycle()  # made by the run: the collector still reclaims it
    gc.collect()
    assert later() is None


def test_calling_it_again_freezes_what_was_made_since(unfrozen: None) -> None:
    first = freeze_startup_objects()
    more = [Node() for _ in range(500)]
    assert freeze_startup_objects() >= first + len(more)
