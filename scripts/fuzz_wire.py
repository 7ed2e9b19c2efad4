"""Coverage-guided fuzzing of the wire decoder (atheris/libFuzzer; not part of CI).

    python scripts/fuzz_wire.py -runs=1000000 -rss_limit_mb=1024 fuzz_corpus/wire   # libFuzzer flags

A fuzz input is a multipart message: [n_parts: u8] then, per part, [length: u32 LE][bytes] (the last part
takes the rest). The corpus starts from every conformance vector (conformance/). Anything but a clean decode
or WireError is a crash; so is an input that makes the decoder allocate more than 64 MiB at once (address-space
limit, fuzz_harness.bounded; also when the decoder wraps the MemoryError in a WireError) or a decoded frame
whose samples do not match its data part. Inputs that cover new code are written to the corpus folder; the
interesting ones are kept in tests/data/fuzz/wire_messages.json and replayed by tests/test_fuzz_regressions.py.
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import atheris
import msgpack  # noqa: F401 - imported first so that only our code is instrumented (numpy would take GiBs)
import numpy  # noqa: F401

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fuzz_harness import fuzz, refused_allocation  # noqa: E402  (beside this script)

with atheris.instrument_imports():
    from sonar_realism.errors import WireError
    from sonar_realism.wire import FRAME_TYPE, decode_message

MAX_PARTS = 5


def split_parts(data: bytes) -> list[bytes]:
    """The parts a fuzz input stands for (see the module doc); never fails."""
    if not data:
        return []
    count, position, parts = min(data[0], MAX_PARTS), 1, []
    for index in range(count):
        if index == count - 1:
            parts.append(data[position:])
            break
        if position + 4 > len(data):
            parts.append(b"")
            continue
        (length,) = struct.unpack_from("<I", data, position)
        position += 4
        parts.append(data[position:position + length])
        position += length
    return parts


def join_parts(parts: list[bytes]) -> bytes:
    """The fuzz input for a message (seeds the corpus from conformance vectors)."""
    out = bytearray([len(parts)])
    for part in parts[:-1]:
        out += struct.pack("<I", len(part)) + part
    return bytes(out + (parts[-1] if parts else b""))


def decode(data: bytes) -> None:
    parts = split_parts(data)
    try:
        message = decode_message(parts)
    except WireError as error:
        assert not refused_allocation(error), "one input needed more than 64 MiB at once (wrapped in a WireError)"
        return
    if message.kind == FRAME_TYPE:
        frame = message.body
        assert frame.intensity.nbytes == len(parts[2]), "decoded samples do not match the data part"


def seeds() -> list[bytes]:
    folders = sorted((ROOT / "conformance").glob("*/*/"))
    return [join_parts([p.read_bytes() for p in sorted(f.glob("part*.bin"), key=lambda p: int(p.stem[4:]))])
            for f in folders]


if __name__ == "__main__":
    fuzz(decode, seeds)
