"""Coverage-guided fuzzing of the Oculus decoders (atheris/libFuzzer; not part of CI).

    python scripts/fuzz_oculus.py -runs=1000000 -rss_limit_mb=1024 fuzz_corpus/oculus   # libFuzzer flags

Each input is tried as one ping message (`decode_ping`) and as a whole recording (`read_oculus` on a file in
/dev/shm when it exists): raw message streams and V1 logs, compressed or not. Anything but frames or
FormatError is a crash, and so is an input that makes a reader allocate more than 64 MiB at once (address-space
limit, fuzz_harness.bounded). The corpus starts from valid pings, raw streams and logs and the inputs earlier
runs found interesting, kept in tests/data/fuzz/oculus_inputs.json and replayed by tests/test_fuzz_regressions.py.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import atheris
import numpy  # noqa: F401 - imported first so that only our code is instrumented (numpy would take GiBs)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fuzz_harness import fuzz  # noqa: E402  (beside this script)

with atheris.instrument_imports():
    from sonar_realism.errors import FormatError
    from sonar_realism.io.oculus import decode_ping, read_oculus

_SCRATCH = Path(tempfile.mkdtemp(prefix="fuzz-oculus-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None))
_FILE = _SCRATCH / "input.bin"


def decode(data: bytes) -> None:
    try:
        frame = decode_ping(data)
        assert frame.intensity.ndim == 2
    except FormatError:
        pass
    _FILE.write_bytes(data)
    try:
        for frame in read_oculus(_FILE):
            assert frame.intensity.ndim == 2
    except FormatError:
        pass


def seeds() -> list[bytes]:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_oculus_fuzz import PINGS, RECORDINGS

    found = json.loads((ROOT / "tests" / "data" / "fuzz" / "oculus_inputs.json").read_text())["inputs"]
    return [*PINGS, *RECORDINGS, *map(bytes.fromhex, found)]


if __name__ == "__main__":
    fuzz(decode, seeds)
