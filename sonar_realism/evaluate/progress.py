"""A progress line on stderr for the long steps (translation, classifier training); no dependency."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def progress(items: Iterable[T], label: str, total: int | None = None) -> Iterator[T]:
    """Yield `items`, redrawing "label  i/total  [####....]  elapsed" on stderr after each."""
    total = total if total is not None else (len(items) if hasattr(items, "__len__") else None)  # type: ignore[arg-type]
    began = time.monotonic()
    done = 0
    for item in items:
        yield item
        done += 1
        if total:
            filled = int(20 * done / total)
            bar = f"[{'#' * filled}{'.' * (20 - filled)}] {done}/{total}"
        else:
            bar = f"{done}"
        print(f"\r{label}  {bar}  {time.monotonic() - began:.0f}s", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr, flush=True)


def report_epoch(label: str) -> Callable[[int, int, float], None]:
    """A `progress(epoch, epochs, loss)` callback that redraws one stderr line per epoch."""
    def callback(epoch: int, epochs: int, loss: float) -> None:
        end = "\n" if epoch == epochs else ""
        print(f"\r{label}  epoch {epoch}/{epochs}  loss {loss:.4f}", end=end, file=sys.stderr, flush=True)
    return callback
