"""What both fuzzers share: the allocation bound on one input and the libFuzzer entry point with seeded corpus.

Imported by scripts/fuzz_wire.py and scripts/fuzz_oculus.py after they instrument the decoders' imports.
"""

from __future__ import annotations

import os
import resource
import sys
from collections.abc import Callable
from pathlib import Path

import atheris

MAX_ALLOCATION = 64 << 20  # the bound on what one input may make a decoder allocate
_PAGE = os.sysconf("SC_PAGE_SIZE")
_STATM = os.open("/proc/self/statm", os.O_RDONLY)


def address_space() -> int:
    """Bytes of address space this process has mapped now (first field of /proc/self/statm)."""
    return int(os.pread(_STATM, 64, 0).split()[0]) * _PAGE


def refused_allocation(error: BaseException) -> bool:
    """Whether `error` is, or was raised while handling, a MemoryError: a decoder that turns every exception
    into its own typed error must not hide an allocation the bound refused."""
    while error is not None:
        if isinstance(error, MemoryError):
            return True
        error = error.__cause__ or error.__context__
    return False


def bounded(decode: Callable[[bytes], None]) -> Callable[[bytes], None]:
    """`decode` with at most MAX_ALLOCATION more address space than the process holds when the input starts: an
    input that needs more gets MemoryError at the allocation and fails like a crash. RLIMIT_AS counts every
    mapping (numpy, zlib, msgpack, Python's heap) and costs three syscalls an input, where tracemalloc made
    every allocation ~5x slower; the limit is lifted again so that libFuzzer's own bookkeeping is not bound."""
    _, hard = resource.getrlimit(resource.RLIMIT_AS)

    def check(data: bytes) -> None:
        resource.setrlimit(resource.RLIMIT_AS, (address_space() + MAX_ALLOCATION, hard))
        try:
            decode(data)
        except MemoryError as error:
            raise AssertionError(f"one input needed more than {MAX_ALLOCATION} bytes at once") from error
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (hard, hard))

    return check


def fuzz(decode: Callable[[bytes], None], seeds: Callable[[], list[bytes]]) -> None:
    """Run libFuzzer on `decode` (sys.argv holds its flags and corpus folders) under the allocation bound
    (`bounded`). The seeds go into the corpus being fuzzed."""
    corpus = [a for a in sys.argv[1:] if not a.startswith("-")]
    if corpus and not any(a.startswith("-merge") for a in sys.argv):
        folder = Path(corpus[0])
        folder.mkdir(parents=True, exist_ok=True)
        for index, seed in enumerate(seeds()):
            (folder / f"seed-{index:03d}").write_bytes(seed)
    atheris.Setup(sys.argv, bounded(decode))
    atheris.Fuzz()
