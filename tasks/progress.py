"""Progress a task reports from inside its work (a clip guarded, a training step logged) to
whoever listens in this process: the command's terminal bar (flows/report.py ``progress``).
Nobody listens in a worker process or on a Ray node, and there a report costs nothing."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

# The topics: clips the face guard went through, training steps, corpus frames written.
GUARDED = "guarded-clips"
TOKENIZER_STEPS, WORLD_MODEL_STEPS = "tokenizer-steps", "world-model-steps"
CORPUS_FRAMES = "corpus-frames"

_listeners: dict[str, list[Callable[..., None]]] = {}
_lock = threading.Lock()


def advance(topic: str, n: int = 1) -> None:
    """``n`` more units of ``topic`` done (from any thread)."""
    _tell(topic, advance=n)


def reached(topic: str, done: int) -> None:
    """``done`` units of ``topic`` done in all (a training step, say)."""
    _tell(topic, completed=done)


def counted(items: Iterable, topic: str) -> Iterator:
    """``items``, one unit of ``topic`` reported as each is taken (frames as a writer takes them)."""
    for item in items:
        yield item
        advance(topic)


def _tell(topic: str, **said: int) -> None:
    with _lock:
        listening = list(_listeners.get(topic, ()))
    for listener in listening:
        listener(**said)


@contextmanager
def listening(topic: str, listener: Callable[..., None]) -> Iterator[None]:
    """``listener(advance=n)`` or ``listener(completed=n)`` on each report about ``topic``
    while the block runs (rich's ``Progress.update`` takes either)."""
    with _lock:
        _listeners.setdefault(topic, []).append(listener)
    try:
        yield
    finally:
        with _lock:
            _listeners[topic].remove(listener)
