"""Progress a task reports from inside its work (a clip guarded, a training step logged) to
whoever listens in this process: the command's terminal bar (flows/report.py ``progress``).
Nobody listens in a worker process or on a Ray node, and there a report costs nothing."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

_listeners: dict[str, list[Callable[[int], None]]] = {}
_lock = threading.Lock()


def advance(topic: str, n: int = 1) -> None:
    """``n`` more units of ``topic`` done (from any thread)."""
    with _lock:
        listening = list(_listeners.get(topic, ()))
    for listener in listening:
        listener(n)


@contextmanager
def listening(topic: str, listener: Callable[[int], None]) -> Iterator[None]:
    with _lock:
        _listeners.setdefault(topic, []).append(listener)
    try:
        yield
    finally:
        with _lock:
            _listeners[topic].remove(listener)
