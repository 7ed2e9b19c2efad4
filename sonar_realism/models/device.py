"""The torch device a `--device` / `device=` setting names, checked once for training and sampling alike, and the
CPU thread count for results that must not depend on it."""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager

import torch

from sonar_realism.errors import ConfigError


def pick_device(name: str) -> torch.device:
    """"auto" (CUDA when there is one, else the CPU), "cpu", "cuda" or "cuda:N"; anything else, or a CUDA
    device this machine lacks, is a ConfigError naming the setting rather than a torch error mid-run."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    match = re.fullmatch(r"cuda(?::(\d+))?", name)
    if match is None:
        raise ConfigError(f"device {name!r}: choose auto, cpu, cuda or cuda:N")
    if not torch.cuda.is_available():
        raise ConfigError(f"device {name}: CUDA is not available on this machine")
    if match.group(1) is not None and int(match.group(1)) >= torch.cuda.device_count():
        raise ConfigError(f"device {name}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return torch.device(name)


@contextmanager
def one_thread() -> Iterator[None]:
    """torch on one thread inside, the caller's count restored after. torch's CPU kernels split their sums by
    thread, so the same inputs and seed trained another model on another thread count: one texture test read
    0.92 on two threads and 0.99 on one, and two calibrations of one recording differed as much as any change
    measured on them (2026-11-24). On one thread a result is the machine's, not its load's or its settings'."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
