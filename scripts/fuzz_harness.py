"""What both fuzzers share: the allocation bound on one input and the libFuzzer entry point with seeded corpus.

Imported by scripts/fuzz_wire.py and scripts/fuzz_oculus.py after they instrument the decoders' imports.
"""

from __future__ import annotations

import sys
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import atheris

MAX_ALLOCATION = 64 << 20  # the bound on what one input may make a decoder allocate


def fuzz(decode: Callable[[bytes], None], seeds: Callable[[], list[bytes]]) -> None:
    """Run libFuzzer on `decode` (sys.argv holds its flags and corpus folders); an input that makes `decode`
    allocate more than MAX_ALLOCATION at once fails like a crash. The seeds go into the corpus being fuzzed."""

    def check(data: bytes) -> None:
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        try:
            decode(data)
        finally:
            peak = tracemalloc.get_traced_memory()[1] - before
        assert peak < MAX_ALLOCATION, f"one input allocated {peak} bytes"

    corpus = [a for a in sys.argv[1:] if not a.startswith("-")]
    if corpus and not any(a.startswith("-merge") for a in sys.argv):
        folder = Path(corpus[0])
        folder.mkdir(parents=True, exist_ok=True)
        for index, seed in enumerate(seeds()):
            (folder / f"seed-{index:03d}").write_bytes(seed)
    tracemalloc.start()
    atheris.Setup(sys.argv, check)
    atheris.Fuzz()
