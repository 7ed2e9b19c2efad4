"""Writes the wire-format conformance vectors (conformance/README.md) from the cases below:
`python conformance/make_vectors.py` (tests/test_conformance.py checks the files match this script).

Expected results are written from the arrays each case starts from, never from decoding the message, so the
files pin the contract of docs/wire-format.md rather than whatever the decoder happens to do.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

HERE = Path(__file__).resolve().parent
TOPIC = "sonar/sim"
STAMP_NS = 1_754_406_000_123_456_789
SENT_NS = 1_754_406_000_200_000_000


@dataclass
class Vector:
    parts: list[bytes]
    expected: dict[str, Any]


@dataclass
class FrameCase:
    """A frame built from arrays: the header is written by hand here, the way another language would."""

    intensity: np.ndarray        # in the dtype and byte order sent
    ranges: Any = "uniform"      # "uniform" -> {start, step, count}; "bytes" -> float64 LE bin; "list"
    azimuths: Any = "bytes"
    header: dict[str, Any] = field(default_factory=dict)  # extra or replaced header keys (None removes one)

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        n_ranges, n_beams = self.intensity.shape[-2:]
        bearings = np.linspace(-0.6, 0.6, n_beams) ** 3 + np.linspace(-0.5, 0.5, n_beams)  # not uniform
        return 0.5 + 0.25 * np.arange(n_ranges), bearings

    def header_map(self) -> dict[str, Any]:
        ranges, azimuths = self.axes()
        header = {"v": 1, "type": "frame", "seq": 42, "stamp_ns": STAMP_NS, "sent_ns": SENT_NS, "frame_id": "sonar",
                  "dtype": self.intensity.dtype.str, "shape": list(self.intensity.shape), "layout": "range_beam",
                  "ranges_m": _axis(ranges, self.ranges), "azimuths_rad": _axis(azimuths, self.azimuths),
                  "meta": {"source": "conformance", "gain_percent": 40.5}}
        header.update(self.header)
        return {k: v for k, v in header.items() if v is not None}

    def parts(self) -> list[bytes]:
        return [TOPIC.encode(), msgpack.packb(self.header_map(), use_bin_type=True), self.intensity.tobytes()]

    def vector(self) -> Vector:
        """The message and what a receiver must decode from it (a valid case)."""
        header, (ranges, azimuths) = self.header_map(), self.axes()
        native = self.intensity.astype(self.intensity.dtype.newbyteorder("="))
        scale = header.get("intensity_scale") or {"u1": 255, "u2": 65535, "u4": 4294967295}.get(
            native.dtype.str[1:], 1.0)
        meta = dict(header.get("meta", {}))
        if "provenance" in header:
            meta["provenance"] = header["provenance"]
        expected = {"kind": "frame", "topic": TOPIC, "seq": header["seq"], "stamp_ns": header["stamp_ns"],
                    "sent_ns": header.get("sent_ns"), "frame_id": header["frame_id"], "dtype": native.dtype.str,
                    "shape": list(native.shape), "intensity_scale": float(scale), "ranges_m": ranges.tolist(),
                    "azimuths_rad": azimuths.tolist(), "meta": meta, "intensity": native.tolist()}
        return Vector(self.parts(), expected)


def _axis(values: np.ndarray, form: str) -> Any:
    if form == "uniform":
        return {"start": float(values[0]), "step": float(values[1] - values[0]), "count": len(values)}
    if form == "bytes":
        return values.astype("<f8").tobytes()
    return values.tolist()


def _values(dtype: str, shape: tuple[int, ...] = (4, 3)) -> np.ndarray:
    rng = np.random.default_rng(7)
    native = np.dtype(dtype).newbyteorder("=")
    if native.kind == "f":
        values = rng.random(shape).astype(native)
    else:
        values = rng.integers(0, np.iinfo(native).max, size=shape, dtype=native, endpoint=True)
    return values.astype(dtype)


def _status(status: dict[str, Any], topic: str = "translator/status") -> Vector:
    header = {"v": 1, "type": "status", "sent_ns": SENT_NS, "status": status}
    return Vector([topic.encode(), msgpack.packb(header, use_bin_type=True)],
                  {"kind": "status", "topic": topic, "sent_ns": SENT_NS, "status": status})


VALID: dict[str, Callable[[], Vector]] = {
    "u1_uniform_ranges_bytes_bearings": lambda: FrameCase(_values("|u1")).vector(),
    "u2_little_endian": lambda: FrameCase(_values("<u2")).vector(),
    "u2_big_endian": lambda: FrameCase(_values(">u2")).vector(),
    "u4_little_endian": lambda: FrameCase(_values("<u4"), ranges="bytes").vector(),
    "u4_big_endian": lambda: FrameCase(_values(">u4")).vector(),
    "f4_list_axes": lambda: FrameCase(_values("<f4"), ranges="list", azimuths="list").vector(),
    "f4_big_endian": lambda: FrameCase(_values(">f4")).vector(),
    "f8_little_endian": lambda: FrameCase(_values("<f8")).vector(),
    "f8_big_endian": lambda: FrameCase(_values(">f8")).vector(),
    "samples_axis_with_provenance": lambda: FrameCase(_values("<f4", (2, 4, 3)), header={
        "provenance": {"node": "translator", "input_seq": 41, "checkpoint_sha256": "ab" * 32}}).vector(),
    "single_sample_axis": lambda: FrameCase(_values("|u1", (1, 4, 3))).vector(),
    "no_sent_ns_no_meta": lambda: FrameCase(_values("|u1"), header={"sent_ns": None, "meta": None}).vector(),
    "uint64_extremes": lambda: FrameCase(_values("|u1"), header={"seq": 2**64 - 1, "stamp_ns": 0,
                                                                 "sent_ns": 2**64 - 1}).vector(),
    "intensity_scale_and_unknown_keys": lambda: FrameCase(_values("<u2"), header={
        "intensity_scale": 4095, "future_key": {"ignored": True}}).vector(),
    "status_heartbeat": lambda: _status({"node": "translator", "state": "running", "seq": 3, "frames_in": 10,
                                         "frames_out": 9, "dropped": 1, "seq_gaps": 0, "malformed": 2,
                                         "inference_ms": 12.5, "uptime_s": 4.0}),
    "end_of_stream": lambda: _status({"node": "sim", "state": "stopped", "end_of_stream": True,
                                      "reason": "finished"}, topic=TOPIC),
}


def _frame_parts(**header: Any) -> list[bytes]:
    return FrameCase(_values("<u2"), header=header).parts()


def _with_header(header: bytes) -> list[bytes]:
    return [TOPIC.encode(), header, _values("<u2").tobytes()]


def _packed(**changes: Any) -> bytes:
    return _frame_parts(**changes)[1]


_NAN = _values("<f4")
_NAN[1, 1] = math.nan
_GOOD = _frame_parts()

INVALID: dict[str, tuple[str, Callable[[], list[bytes]]]] = {
    # name: (the WireError field a receiver must name, the message parts)
    "one_part": ("parts", lambda: [TOPIC.encode()]),
    "four_parts": ("parts", lambda: [*_GOOD, b""]),
    "frame_without_data": ("parts", lambda: _GOOD[:2]),
    "status_with_data": ("parts", lambda: [*_status({"node": "n", "state": "running"}).parts, b""]),
    "topic_not_utf8": ("topic", lambda: [b"\xff\xfe", *_GOOD[1:]]),
    "topic_too_long": ("topic", lambda: [b"t" * 1025, *_GOOD[1:]]),
    "header_empty": ("header", lambda: _with_header(b"")),
    "header_garbage": ("header", lambda: _with_header(b"\xc1 not msgpack")),
    "header_truncated": ("header", lambda: _with_header(_GOOD[1][:-3])),
    "header_trailing_bytes": ("header", lambda: _with_header(_GOOD[1] + b"\x00")),
    "header_not_a_map": ("header", lambda: _with_header(msgpack.packb([1, 2, 3]))),
    "header_int_key": ("header", lambda: _with_header(msgpack.packb({1: 2}))),
    "header_too_large": ("header", lambda: _with_header(_packed(meta={"pad": "x" * 65536}))),
    "ext_type_in_meta": ("header", lambda: _with_header(_packed(meta={"x": msgpack.ExtType(5, b"abc")}))),
    "timestamp_ext_in_meta": ("header", lambda: _with_header(_packed(meta={"t": msgpack.Timestamp(5, 0)}))),
    "timestamp_ext_nested": ("header", lambda: _with_header(_packed(meta={"a": [{"t": msgpack.Timestamp(1, 2)}]}))),
    "version_2": ("v", lambda: _with_header(_packed(v=2))),
    "version_missing": ("v", lambda: _with_header(_packed(v=None))),
    "version_bool": ("v", lambda: _with_header(_packed(v=True))),
    "type_unknown": ("type", lambda: _with_header(_packed(type="image"))),
    "seq_missing": ("seq", lambda: _with_header(_packed(seq=None))),
    "seq_negative": ("seq", lambda: _with_header(_packed(seq=-1))),
    "stamp_ns_float": ("stamp_ns", lambda: _with_header(_packed(stamp_ns=1.5e18))),
    "sent_ns_string": ("sent_ns", lambda: _with_header(_packed(sent_ns="now"))),
    "dtype_signed": ("dtype", lambda: _with_header(_packed(dtype="<i2"))),
    "dtype_float16": ("dtype", lambda: _with_header(_packed(dtype="<f2"))),
    "shape_zero": ("shape", lambda: _with_header(_packed(shape=[0, 3]))),
    "shape_one_axis": ("shape", lambda: _with_header(_packed(shape=[12]))),
    "layout_unknown": ("layout", lambda: _with_header(_packed(layout="beam_range"))),
    "data_short": ("data", lambda: [*_GOOD[:2], _GOOD[2][:-2]]),
    "data_long": ("data", lambda: [*_GOOD[:2], _GOOD[2] + b"\x00\x00"]),
    "ranges_count_mismatch": ("ranges_m", lambda: _with_header(_packed(ranges_m={"start": 0.5, "step": 0.25,
                                                                                 "count": 5}))),
    "ranges_decreasing": ("ranges_m", lambda: _with_header(_packed(ranges_m=[2.0, 1.5, 1.0, 0.5]))),
    "ranges_negative": ("ranges_m", lambda: _with_header(_packed(ranges_m=[-1.0, 0.0, 1.0, 2.0]))),
    "azimuths_wrong_byte_count": ("azimuths_rad", lambda: _with_header(_packed(azimuths_rad=b"\x00" * 8))),
    "azimuths_in_degrees": ("azimuths_rad", lambda: _with_header(_packed(azimuths_rad=[-60.0, 0.0, 60.0]))),
    "azimuths_wrong_type": ("azimuths_rad", lambda: _with_header(_packed(azimuths_rad="left"))),
    "nan_sample": ("intensity", lambda: [TOPIC.encode(), FrameCase(_NAN).parts()[1], _NAN.tobytes()]),
    "meta_not_a_map": ("meta", lambda: _with_header(_packed(meta=[1]))),
    "provenance_not_a_map": ("provenance", lambda: _with_header(_packed(provenance="me"))),
    "intensity_scale_string": ("intensity_scale", lambda: _with_header(_packed(intensity_scale="full"))),
    "frame_id_not_a_string": ("frame_id", lambda: _with_header(_packed(frame_id=3))),
    "status_missing": ("status", lambda: [b"n/status", msgpack.packb({"v": 1, "type": "status"})]),
    "status_without_state": ("status.state", lambda: [b"n/status", msgpack.packb(
        {"v": 1, "type": "status", "status": {"node": "n"}})]),
    "status_negative_counter": ("status.frames_in", lambda: [b"n/status", msgpack.packb(
        {"v": 1, "type": "status", "status": {"node": "n", "state": "running", "frames_in": -1}})]),
}


def build() -> dict[str, Vector]:
    vectors = {f"valid/{name}": make() for name, make in VALID.items()}
    for name, (field_name, make) in INVALID.items():
        parts = make()
        expected = {"error_field": field_name, "topic": None if field_name == "topic" else parts[0].decode()}
        vectors[f"invalid/{name}"] = Vector(parts, expected)
    return vectors


def write(folder: Path = HERE) -> int:
    for kind in ("valid", "invalid"):
        shutil.rmtree(folder / kind, ignore_errors=True)
    for name, vector in build().items():
        target = folder / name
        target.mkdir(parents=True)
        for number, part in enumerate(vector.parts, start=1):
            (target / f"part{number}.bin").write_bytes(part)
        (target / "expected.json").write_text(json.dumps(vector.expected, indent=1) + "\n")
    return len(VALID) + len(INVALID)


if __name__ == "__main__":
    print(f"wrote {write()} vectors to {HERE}")
    sys.exit(0)
