"""Warm workers: what a worker started for one evaluation, kept for its next.

Starting an evaluation's simulator process costs about a quarter of a second of one core in
Python imports before the flight begins, and MAVSDK a connection; a campaign pays that on every
evaluation. A worker that flies evaluation after evaluation with the same options keeps one
stack (harness/flight/evaluation.py builds it: the simulator with the SUT inside, serving
flight after flight) and hands it to the next evaluation if the last flight ended cleanly.

One stack per process: an evaluation with other options closes the kept one first. The owner
of the process closes what is kept (`close_all`) before it exits or when its campaign ends.
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

_kept: dict[str, Reusable] = {}


@contextmanager
def reuse(key: str, start: Callable[[], R]) -> Iterator[R]:
    """The stack kept under key if it is still fit, else a new one from start(); kept again
    afterwards if it is still fit then, closed if not or if the body raised."""
    kept = _kept.pop(key, None)
    close_all()
    if kept is not None and not kept.reusable():
        kept.close()
        kept = None
    stack = kept if kept is not None else start()
    try:
        yield stack
    except BaseException:
        stack.close()
        raise
    if stack.reusable():
        _kept[key] = stack
    else:
        stack.close()


def close_all() -> None:
    while _kept:
        _key, stack = _kept.popitem()
        try:
            stack.close()
        except Exception as error:  # closing is best effort: its processes die with this one anyway
            log.warning("closing a kept stack failed: %s", error)
