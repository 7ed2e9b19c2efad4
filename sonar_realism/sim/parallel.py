"""Frames rendered by a pool of processes: frame i depends only on (world, seed, i), so frames are independent
and the output is the same, in the same order, whatever the number of workers.

The pool is forked after the frame function is in place, so the world (seabed, objects, lambdas) is inherited,
never pickled; only the index goes out and the (frame, mask) pair comes back.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator
from typing import TypeVar

import cv2

T = TypeVar("T")

_make_frame: Callable[[int], object] | None = None


def _call(index: int) -> object:
    assert _make_frame is not None
    return _make_frame(index)


def frames_in_parallel(make_frame: Callable[[int], T], n: int, workers: int) -> Iterator[T]:
    """make_frame(0..n-1), in order; with workers > 1 on that many forked processes."""
    global _make_frame
    if workers <= 1 or n <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        for index in range(n):
            yield make_frame(index)
        return
    _make_frame = make_frame
    # one cv2 thread per worker: the workers already fill the cores, and cv2's pool of threads must be down when
    # forking (a child cannot reconfigure threads it did not inherit)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with multiprocessing.get_context("fork").Pool(min(workers, n)) as pool:
            yield from pool.imap(_call, range(n), chunksize=2)  # type: ignore[misc]
    finally:
        cv2.setNumThreads(threads)
        _make_frame = None
