"""Random draws that a search repeats.

A parameter search evaluates every candidate under common random numbers: a generator seeded alike for each
evaluation, so each evaluation draws the same noise fields again (a quarter of a diagnosis' time went to drawing
them). Inside `remembering_draws()`, a function marked `@remembered_draw` keeps what it drew under the generator's
state and its other arguments; called again from that state with those arguments, it returns a copy and moves the
generator on exactly as the draw did. So results are bit-identical with and without the memo. Outside the context
nothing is kept (a simulator never draws the same field twice). Each thread has its own memo (a forked worker starts
with a copy of its parent's)."""

from __future__ import annotations

import contextlib
import functools
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import numpy as np

Draw = TypeVar("Draw", bound=Callable[..., Any])


class _Memo:
    """Least recently used draws, up to `limit_bytes` of arrays."""

    def __init__(self, limit_bytes: int) -> None:
        self.limit_bytes = limit_bytes
        self.bytes = 0
        self.entries: OrderedDict[tuple, tuple[Any, dict]] = OrderedDict()

    def get(self, key: tuple) -> tuple[Any, dict] | None:
        entry = self.entries.get(key)
        if entry is not None:
            self.entries.move_to_end(key)
        return entry

    def put(self, key: tuple, value: Any, state_after: dict) -> None:
        """Keep a copy of `value` (the caller goes on with its own) unless it alone is over the limit."""
        size = sum(a.nbytes for a in _arrays(value))
        if size > self.limit_bytes:
            return
        self.entries[key] = (_copied(value), state_after)
        self.bytes += size
        while self.bytes > self.limit_bytes:
            _, (old, _) = self.entries.popitem(last=False)
            self.bytes -= sum(a.nbytes for a in _arrays(old))


_local = threading.local()


def current_memo() -> _Memo | None:
    """This thread's memo, None outside `remembering_draws()`."""
    return getattr(_local, "memo", None)


@contextlib.contextmanager
def remembering_draws(limit_mb: int = 256) -> Iterator[None]:
    """Within this block `@remembered_draw` functions remember up to `limit_mb` MB of draws (least recently used
    go first; 0: nothing, a baseline for benchmarks). Nested blocks share the outermost one's memo; it is emptied
    when that block ends."""
    if current_memo() is not None:
        yield
        return
    _local.memo = _Memo(limit_mb * 2 ** 20)
    try:
        yield
    finally:
        _local.memo = None


def remembered_draw(draw: Draw) -> Draw:
    """Mark `draw(rng, *args)` (args hashable; returns an array or a tuple of arrays) as repeatable by the memo."""

    @functools.wraps(draw)
    def wrapper(rng: np.random.Generator, *args: Any) -> Any:
        memo = current_memo()
        if memo is None or memo.limit_bytes == 0:  # a 0 MB memo is the plain draw, as the benchmark's baseline
            return draw(rng, *args)
        key = (draw.__qualname__, _frozen(rng.bit_generator.state), args)
        entry = memo.get(key)
        if entry is None:
            value = draw(rng, *args)
            memo.put(key, value, rng.bit_generator.state)
            return value
        value, state_after = entry
        rng.bit_generator.state = state_after
        return _copied(value)

    return wrapper  # type: ignore[return-value]


def _frozen(value: Any) -> Any:
    """A hashable form of a bit generator's state (nested dicts, ints, arrays)."""
    if isinstance(value, dict):
        return tuple((k, _frozen(v)) for k, v in sorted(value.items()))
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.shape, value.tobytes()
    return value


def _arrays(value: Any) -> tuple[np.ndarray, ...]:
    return value if isinstance(value, tuple) else (value,)


def _copied(value: Any) -> Any:
    # callers may write into what they get, so the memo never hands out its own arrays
    return tuple(a.copy() for a in value) if isinstance(value, tuple) else value.copy()
