"""Warm workers: what a worker started for one evaluation, kept for its next.

Starting an evaluation's simulator process costs about a quarter of a second of one core in
Python imports before the flight begins, and MAVSDK a connection; a campaign pays that on every
evaluation. A worker that flies evaluation after evaluation with the same options keeps one
stack (harness/flight/stack.py builds it: the simulator with the SUT inside, serving
flight after flight) and hands it to the next evaluation if the last flight ended cleanly.

One stack per process: a warm evaluation with other options closes the kept one first. The
owner of the process closes what is kept (`close_all`) before it exits or when its campaign ends.
"""

from __future__ import annotations

import logging
from contextlib import contextmanager
from typing import Callable, Iterator, Protocol, TypeVar

log = logging.getLogger(__name__)


class Reusable(Protocol):
    def reusable(self) -> bool:
        """Whether the last use left it fit for the next: still running, nothing half-done."""

    def close(self) -> None: ...


R = TypeVar("R", bound=Reusable)

_kept: tuple[str, Reusable] | None = None  # (the options it was started for, the stack)


@contextmanager
def reuse(key: str, start: Callable[[], R]) -> Iterator[R]:
    """The stack kept for key if it is still fit, else a new one from start(); kept again
    afterwards if it is still fit then. Whatever is not kept is closed, however the body ends
    (an executor's time limit arrives as an exception at any point)."""
    global _kept
    kept, _kept = _kept, None
    stack = None
    try:
        if kept is not None:
            if kept[0] == key and kept[1].reusable():
                stack = kept[1]
            else:
                _close(kept[1])
            kept = None
        if stack is None:
            stack = start()
        yield stack
        if stack.reusable():
            _kept, stack = (key, stack), None
    finally:
        for leftover in (kept[1] if kept is not None else None, stack):
            if leftover is not None:
                _close(leftover)


def close_all() -> None:
    global _kept
    kept, _kept = _kept, None
    if kept is not None:
        _close(kept[1])


def _close(stack: Reusable) -> None:
    try:
        stack.close()
    except Exception as error:  # closing is best effort: its processes die with this one anyway
        log.warning("closing a kept stack failed: %s", error)
