"""Oculus decode throughput against a plain read of the same file, measured in the same run.

Generates multi-ping recordings (512 beams x 1000 ranges, 8 and 16-bit, raw message stream and V1 log,
plus a qCompress'd log), reads each one plainly (1 MiB chunks) and decodes it with read_oculus, best of
`repeats` interleaved runs with a warm page cache. Goal: decode >= 0.5x the plain read.

    nice python bench/bench_oculus.py [--size-mb 200] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io.oculus import encode_ping, read_oculus, write_oculus_log

N_BEAMS, N_RANGES = 512, 1000
CASES = (("raw stream", np.uint8, False), ("raw stream", np.uint16, False), ("V1 log", np.uint8, False),
         ("V1 log", np.uint16, False), ("V1 log, qCompress", np.uint16, True))


def pings(count: int, dtype: type[np.unsignedinteger], seed: int = 0) -> Iterator[SonarImage]:
    """Speckle-like pings (Rayleigh amplitudes), each a shifted copy of one random image."""
    rng = np.random.default_rng(seed)
    full_scale = np.iinfo(dtype).max
    base = np.clip(rng.rayleigh(0.15, size=(N_RANGES, N_BEAMS)) * full_scale, 0, full_scale).astype(dtype)
    ranges, azimuths = uniform_ranges(N_RANGES, 30.0), uniform_azimuths(N_BEAMS, np.radians(130))
    for index in range(count):
        yield SonarImage(np.roll(base, index, axis=0), ranges, azimuths, seq=index,
                         stamp_ns=1_754_406_000_000_000_000 + index * 66_666_000)


def write_recording(path: Path, kind: str, dtype: type[np.unsignedinteger], compress: bool, size_mb: float) -> int:
    count = max(1, int(size_mb * 1e6 / (N_RANGES * N_BEAMS * np.dtype(dtype).itemsize)))
    if kind == "raw stream":
        with open(path, "wb") as out:
            for frame in pings(count, dtype):
                out.write(encode_ping(frame))
        return count
    return write_oculus_log(pings(count, dtype), path, compress=compress)


def plain_read_seconds(path: Path) -> float:
    start = time.perf_counter()
    with open(path, "rb", buffering=0) as handle:
        while handle.read(1 << 20):
            pass
    return time.perf_counter() - start


def decode_seconds(path: Path, expected: int) -> float:
    start = time.perf_counter()
    decoded = sum(1 for _ in read_oculus(path))
    elapsed = time.perf_counter() - start
    if decoded != expected:
        raise RuntimeError(f"{path}: decoded {decoded} pings, wrote {expected}")
    return elapsed


def run(size_mb: float = 200.0, repeats: int = 3) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for kind, dtype, compress in CASES:
            path = Path(folder) / "recording.bin"
            count = write_recording(path, kind, dtype, compress, size_mb / 4 if compress else size_mb)
            file_mb = path.stat().st_size / 1e6
            read_s, decode_s = float("inf"), float("inf")
            for _ in range(repeats):
                read_s = min(read_s, plain_read_seconds(path))
                decode_s = min(decode_s, decode_seconds(path, count))
            rows.append({"case": f"{kind}, {8 * np.dtype(dtype).itemsize}-bit", "pings": count,
                         "file_mb": round(file_mb, 1), "plain_read_mb_s": round(file_mb / read_s),
                         "decode_mb_s": round(file_mb / decode_s), "decode_vs_read": round(read_s / decode_s, 2)})
            path.unlink()
    return rows


def markdown(rows: list[dict]) -> str:
    header = ("| case | pings | file MB | plain read MB/s | decode MB/s | decode / read |\n"
              "|---|---:|---:|---:|---:|---:|")
    lines = [f"| {r['case']} | {r['pings']} | {r['file_mb']} | {r['plain_read_mb_s']} | {r['decode_mb_s']} | "
             f"{r['decode_vs_read']} |" for r in rows]
    return "\n".join([header, *lines])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-mb", type=float, default=200.0, help="size of each generated recording")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(markdown(run(args.size_mb, args.repeats)))


if __name__ == "__main__":
    main()
