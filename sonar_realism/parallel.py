"""Independent work on several cores (a simulator's frames, a diagnosis step's fits, a texture mixture's
generators): `parallel_map(task, items, workers)` and its streaming form `parallel_imap` run task(item) for every
item in forked worker processes, in order. The task is usually a closure over a world, frames or statistics; forking
hands it and the items to the workers as they are (nothing is pickled but an index and the result), so the result is
the same, in the same order, whatever the number of workers."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
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


def parallel_imap(task: Callable[[I], T], items: Sequence[I], workers: int, chunksize: int = 1) -> Iterator[T]:
    """task(item) for item in items, yielded in order as they are done by up to `workers` forked processes. Serial
    where forking is not available, for a single item or worker, inside a worker (workers do not fork again) and
    while another pool of this module is running."""
    global _task, _items
    serial = workers <= 1 or len(items) <= 1 or _in_worker or _task is not None
    if serial or "fork" not in multiprocessing.get_all_start_methods():
        for item in items:
            yield task(item)
        return
    _task, _items = task, items
    # cv2's thread pool must be down when forking (a child cannot reconfigure the threads it did not inherit), and
    # one thread per worker is what the workers should use anyway
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with multiprocessing.get_context("fork").Pool(min(workers, len(items)), initializer=_start_worker) as pool:
            yield from pool.imap(_run, range(len(items)), chunksize=chunksize)
    finally:
        cv2.setNumThreads(threads)
        _task, _items = None, ()


def parallel_map(task: Callable[[I], T], items: Sequence[I], workers: int) -> list[T]:
    """[task(item) for item in items], computed as `parallel_imap` computes it."""
    return list(parallel_imap(task, items, workers))
