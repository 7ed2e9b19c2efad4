"""Independent fits on several cores (a diagnosis step's, a texture mixture's generators): `parallel_map(task,
items, workers)` runs task(item) for every item in forked worker processes. The task is usually a closure over
frames and statistics; forking hands it and the items to the workers as they are (nothing is pickled but an index
and the result)."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import cv2

T = TypeVar("T")
I = TypeVar("I")  # noqa: E741

_task: Callable[[Any], Any] | None = None
_items: Sequence[Any] = ()
_in_worker = False


def _start_worker() -> None:
    global _in_worker
    _in_worker = True


def _run(index: int) -> Any:
    assert _task is not None
    return _task(_items[index])


def parallel_map(task: Callable[[I], T], items: Sequence[I], workers: int) -> list[T]:
    """[task(item) for item in items], computed by up to `workers` forked processes; in order. Serial where forking
    is not available, for a single item or worker, and inside a worker (workers do not fork again)."""
    global _task, _items
    if workers <= 1 or len(items) <= 1 or _in_worker or "fork" not in multiprocessing.get_all_start_methods():
        return [task(item) for item in items]
    _task, _items = task, items
    # cv2's thread pool must be down when forking (a child cannot reconfigure the threads it did not inherit), and
    # one thread per worker is what the workers should use anyway
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with multiprocessing.get_context("fork").Pool(min(workers, len(items)), initializer=_start_worker) as pool:
            return pool.map(_run, range(len(items)), chunksize=1)
    finally:
        cv2.setNumThreads(threads)
        _task, _items = None, ()
