"""ZeroMQ wire format: one multipart message per frame or status report (spec: docs/wire-format.md).

    frame:  [topic, header, data]   header = msgpack map, data = raw intensity bytes (C order)
    status: [topic, header]         header = msgpack map with a "status" map

Pixels never go through msgpack (it would copy them) and nothing is ever pickled. Encoding hands the
array's own memory to ZeroMQ; decoding returns a numpy view over the received buffer (zmq.Frame with
recv_multipart(copy=False), or bytes), so a 2 MiB frame crosses the socket without a Python-level copy.
This module does not import zmq: it works on anything that exposes the buffer protocol or `.buffer`.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import msgpack
import numpy as np

from sonar_realism.errors import FrameError, WireError
from sonar_realism.frames import SUPPORTED_DTYPES, SonarImage

WIRE_VERSION = 1
FRAME_TYPE = "frame"
STATUS_TYPE = "status"
LAYOUT = "range_beam"  # C order, [sample,] range bin (nearest first), beam (left to right)
MAX_HEADER_BYTES = 64 * 1024
MAX_TOPIC_BYTES = 1024
STATUS_STATES = ("starting", "running", "stopping", "stopped", "error")

# Byte-order-explicit dtype strings accepted on the wire ('|u1' has no byte order; '<' is recommended).
WIRE_DTYPES: dict[str, np.dtype] = {dtype.newbyteorder(order).str: dtype.newbyteorder(order)
                                    for dtype in SUPPORTED_DTYPES for order in "<>"}

# A uniform axis is sent as {start, step, count} when rebuilding it is this close (fraction of one step);
# geometry this close is the same to any sonar, and it keeps headers of 8192-bin frames tiny.
_UNIFORM_TOLERANCE = 1e-9

_REQUIRED_FRAME_KEYS = {"v", "type", "seq", "stamp_ns", "frame_id", "dtype", "shape", "layout", "ranges_m",
                        "azimuths_rad"}
_STATUS_COUNTERS = ("seq", "frames_in", "frames_out", "dropped", "seq_gaps", "malformed")
_STATUS_NUMBERS = ("stamp_ns", "uptime_s", "inference_ms")


def encode_frame(frame: SonarImage, topic: str, provenance: dict | None = None) -> list:
    """Parts [topic, header, data] of one frame message; data is the intensity's own memory when C-contiguous.

    `provenance` (input seq/stamp, checkpoint hash, node name, ...) travels in the header and comes back as
    `frame.meta["provenance"]`; without it, an existing `frame.meta["provenance"]` is forwarded.
    """
    topic_bytes = _encode_topic(topic)
    intensity = np.ascontiguousarray(frame.intensity)  # no copy when already C-contiguous
    meta = dict(frame.meta)
    carried_provenance = meta.pop("provenance", None)
    if provenance is None:
        provenance = carried_provenance
    header = {
        "v": WIRE_VERSION,
        "type": FRAME_TYPE,
        "seq": frame.seq,
        "stamp_ns": frame.stamp_ns,
        "sent_ns": time.time_ns(),
        "frame_id": frame.frame_id,
        "dtype": intensity.dtype.str,
        "shape": list(intensity.shape),
        "layout": LAYOUT,
        "ranges_m": _encode_axis(frame.ranges_m),
        "azimuths_rad": _encode_axis(frame.azimuths_rad),
        "intensity_scale": frame.intensity_scale,
        "meta": meta,
    }
    if provenance is not None:
        if not isinstance(provenance, Mapping):
            raise WireError(f"provenance: expected a dict, got {type(provenance).__name__}")
        header["provenance"] = dict(provenance)
    return [topic_bytes, _pack_header(header), memoryview(intensity).cast("B")]


def encode_status(topic: str, status: dict) -> list:
    """Parts [topic, header] of one status/heartbeat message (fields: docs/wire-format.md, "Status")."""
    topic_bytes = _encode_topic(topic)
    if not isinstance(status, Mapping):
        raise WireError(f"status: expected a dict, got {type(status).__name__}")
    checked = _check_status(dict(status))
    header = {"v": WIRE_VERSION, "type": STATUS_TYPE, "sent_ns": time.time_ns(), "status": checked}
    return [topic_bytes, _pack_header(header)]


def decode_message(parts: Sequence[Any]) -> tuple[str, str, SonarImage | dict]:
    """(topic, type, SonarImage or status dict) of one received multipart message; WireError if malformed."""
    if not isinstance(parts, Sequence) or len(parts) not in (2, 3):
        count = len(parts) if isinstance(parts, Sequence) else type(parts).__name__
        raise WireError(f"message: expected 3 parts [topic, header, data] or 2 [topic, header], got {count}")
    topic = _decode_topic(parts[0])
    header = _unpack_header(parts[1])
    kind = header.get("type")
    if kind == FRAME_TYPE:
        if len(parts) != 3:
            raise WireError(f"topic {topic!r}: a frame message has 3 parts [topic, header, data], got {len(parts)}")
        return topic, FRAME_TYPE, _decode_frame_body(topic, header, parts[2])
    if kind == STATUS_TYPE:
        if len(parts) != 2:
            raise WireError(f"topic {topic!r}: a status message has 2 parts [topic, header], got {len(parts)}")
        _require_keys(topic, header, {"status"})
        status = header.get("status")
        if not isinstance(status, dict):
            raise WireError(f"topic {topic!r}: header field 'status': expected a map")
        return topic, STATUS_TYPE, _check_status(status, topic)
    raise WireError(f"topic {topic!r}: header field 'type': expected {FRAME_TYPE!r} or {STATUS_TYPE!r}, "
                    f"got {kind!r}")


def decode_frame(parts: Sequence[Any]) -> tuple[str, SonarImage]:
    """(topic, SonarImage) of a frame message; WireError if the message is malformed or not a frame."""
    topic, kind, body = decode_message(parts)
    if kind != FRAME_TYPE:
        raise WireError(f"topic {topic!r}: expected a frame message, got type {kind!r}")
    return topic, body


def _decode_frame_body(topic: str, header: dict, data: Any) -> SonarImage:
    where = f"topic {topic!r}"
    _require_keys(topic, header, _REQUIRED_FRAME_KEYS)
    dtype_name = header["dtype"]
    if not isinstance(dtype_name, str) or dtype_name not in WIRE_DTYPES:
        raise WireError(f"{where}: header field 'dtype': unknown dtype {dtype_name!r}; "
                        f"supported: {', '.join(sorted(WIRE_DTYPES))}")
    dtype = WIRE_DTYPES[dtype_name]
    shape = header["shape"]
    if (not isinstance(shape, list) or len(shape) not in (2, 3)
            or not all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in shape)):
        raise WireError(f"{where}: header field 'shape': expected [n_ranges, n_beams] or "
                        f"[n_samples, n_ranges, n_beams] of positive ints, got {shape!r}")
    if header["layout"] != LAYOUT:
        raise WireError(f"{where}: header field 'layout': expected {LAYOUT!r}, got {header['layout']!r}")
    buffer = _as_buffer(data, where)
    expected = math.prod(shape) * dtype.itemsize
    if buffer.nbytes != expected:
        raise WireError(f"{where}: data part: expected {expected} bytes for shape {shape} of {dtype_name}, "
                        f"got {buffer.nbytes}")
    intensity = np.frombuffer(buffer, dtype=dtype).reshape(shape)  # a view over the received message
    # Read-only: over inproc the received message is the sender's own array, which a write would corrupt.
    intensity.flags.writeable = False

    meta = header.get("meta", {})
    if not isinstance(meta, dict):
        raise WireError(f"{where}: header field 'meta': expected a map, got {type(meta).__name__}")
    provenance = header.get("provenance")
    if provenance is not None:
        if not isinstance(provenance, dict):
            raise WireError(f"{where}: header field 'provenance': expected a map, got {type(provenance).__name__}")
        meta = {**meta, "provenance": provenance}
    scale = header.get("intensity_scale", 0.0)
    if not isinstance(scale, int | float) or isinstance(scale, bool):
        raise WireError(f"{where}: header field 'intensity_scale': expected a number, got {scale!r}")
    for name in ("seq", "stamp_ns"):
        if not isinstance(header[name], int) or isinstance(header[name], bool):
            raise WireError(f"{where}: header field {name!r}: expected an int, got {header[name]!r}")
    try:
        return SonarImage(
            intensity=intensity,
            ranges_m=_decode_axis(header["ranges_m"], "ranges_m", shape[-2], where),
            azimuths_rad=_decode_axis(header["azimuths_rad"], "azimuths_rad", shape[-1], where),
            stamp_ns=header["stamp_ns"],
            seq=header["seq"],
            frame_id=header["frame_id"],
            intensity_scale=scale,
            meta=meta,
        )
    except FrameError as error:
        raise WireError(f"{where}: invalid frame: {error}") from error


def _encode_axis(values: np.ndarray) -> dict | bytes:
    count = len(values)
    if count > 1:
        start = float(values[0])
        step = (float(values[-1]) - start) / (count - 1)
        tolerance = _UNIFORM_TOLERANCE * step
        middle = count // 2
        # The middle bin rejects a non-uniform (Oculus) bearing table without building the whole axis.
        if abs(start + step * middle - float(values[middle])) <= tolerance:
            error = np.arange(count, dtype=np.float64)
            error *= step
            error += start
            error -= values
            if max(error.max(), -error.min()) <= tolerance:
                return {"start": start, "step": step, "count": count}
    return np.ascontiguousarray(values, dtype="<f8").tobytes()


def _decode_axis(value: Any, name: str, count: int, where: str) -> np.ndarray:
    """Axis from the uniform form {start, step, count}, float64 little-endian bytes, or a list of numbers."""
    if isinstance(value, dict):
        if set(value) != {"start", "step", "count"}:
            raise WireError(f"{where}: header field {name!r}: a uniform axis has exactly the keys start, step, "
                            f"count; got {sorted(map(str, value))}")
        start, step, n = value["start"], value["step"], value["count"]
        if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in (start, step)):
            raise WireError(f"{where}: header field {name!r}: start and step must be numbers")
        if not isinstance(n, int) or n != count:
            raise WireError(f"{where}: header field {name!r}: count {n!r} does not match the shape ({count})")
        return _uniform_axis(float(start), float(step), count)
    if isinstance(value, bytes):
        if len(value) != 8 * count:
            raise WireError(f"{where}: header field {name!r}: expected {count} float64 values "
                            f"({8 * count} bytes), got {len(value)} bytes")
        return np.frombuffer(value, dtype="<f8")
    if isinstance(value, list):
        if len(value) != count or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in value):
            raise WireError(f"{where}: header field {name!r}: expected a list of {count} numbers")
        return np.asarray(value, dtype=np.float64)
    raise WireError(f"{where}: header field {name!r}: expected {{start, step, count}}, float64 bytes or a list, "
                    f"got {type(value).__name__}")


@functools.lru_cache(maxsize=64)
def _uniform_axis(start: float, step: float, count: int) -> np.ndarray:
    """A stream repeats its geometry every frame, so each uniform axis is built once (read-only, shared)."""
    with np.errstate(all="ignore"):  # an absurd start/step gives inf/NaN, which SonarImage then rejects
        axis = start + step * np.arange(count)
    axis.flags.writeable = False
    return axis


def _check_status(status: dict, topic: str | None = None) -> dict:
    where = f"topic {topic!r}: status" if topic is not None else "status"
    if not all(isinstance(key, str) for key in status):
        raise WireError(f"{where}: keys must be strings")
    node, state = status.get("node"), status.get("state")
    if not isinstance(node, str) or not node:
        raise WireError(f"{where}: field 'node': expected a non-empty node name, got {node!r}")
    if state not in STATUS_STATES:
        raise WireError(f"{where}: field 'state': expected one of {', '.join(STATUS_STATES)}, got {state!r}")
    for name in _STATUS_COUNTERS:
        value = status.get(name, 0)
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < 0:
            raise WireError(f"{where}: field {name!r}: expected a non-negative int, got {value!r}")
    for name in _STATUS_NUMBERS:
        value = status.get(name, 0)
        if not isinstance(value, int | float | np.number) or isinstance(value, bool) or not math.isfinite(value):
            raise WireError(f"{where}: field {name!r}: expected a finite number, got {value!r}")
    return status


def _pack_header(header: dict) -> bytes:
    try:
        packed = msgpack.packb(header, use_bin_type=True, default=_plain_value)
    except (TypeError, ValueError, OverflowError) as error:
        raise WireError(f"header: cannot encode ({error}); meta, provenance and status must be JSON-like "
                        f"(dict, list, str, int, float, bool, None, bytes)") from error
    if len(packed) > MAX_HEADER_BYTES:
        raise WireError(f"header: {len(packed)} bytes exceeds the {MAX_HEADER_BYTES}-byte limit; "
                        f"keep large data out of meta/provenance")
    return packed


def _plain_value(value: Any) -> Any:
    """msgpack fallback for numpy scalars and small arrays that land in meta (e.g. np.float32 gains)."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot serialize {type(value).__name__}")


def _unpack_header(part: Any) -> dict:
    buffer = _as_buffer(part, "header part")
    if buffer.nbytes > MAX_HEADER_BYTES:
        raise WireError(f"header: {buffer.nbytes} bytes exceeds the {MAX_HEADER_BYTES}-byte limit")
    try:
        header = msgpack.unpackb(buffer, raw=False, ext_hook=_reject_ext, strict_map_key=True)
    except Exception as error:  # msgpack raises many types for corrupt input; all mean "not our header"
        raise WireError(f"header: not valid msgpack ({type(error).__name__}: {error})") from error
    if not isinstance(header, dict):
        raise WireError(f"header: expected a msgpack map, got {type(header).__name__}")
    version = header.get("v")
    if type(version) is not int or version != WIRE_VERSION:
        raise WireError(f"header field 'v': wire version {version!r} is not supported (this reader speaks "
                        f"version {WIRE_VERSION}); upgrade the older side")
    return header


def _reject_ext(code: int, data: bytes) -> Any:
    raise WireError(f"header: msgpack extension type {code} is not part of the wire format")


def _require_keys(topic: str, header: dict, required: set[str]) -> None:
    missing = sorted(required - set(header))
    if missing:
        raise WireError(f"topic {topic!r}: header is missing field(s) {', '.join(missing)}")


def _encode_topic(topic: str) -> bytes:
    if not isinstance(topic, str):
        raise WireError(f"topic: expected str, got {type(topic).__name__}")
    encoded = topic.encode("utf-8")
    if len(encoded) > MAX_TOPIC_BYTES:
        raise WireError(f"topic: {len(encoded)} bytes exceeds the {MAX_TOPIC_BYTES}-byte limit")
    return encoded


def _decode_topic(part: Any) -> str:
    buffer = _as_buffer(part, "topic part")
    if buffer.nbytes > MAX_TOPIC_BYTES:
        raise WireError(f"topic: {buffer.nbytes} bytes exceeds the {MAX_TOPIC_BYTES}-byte limit")
    try:
        return bytes(buffer).decode("utf-8")
    except UnicodeDecodeError as error:
        raise WireError(f"topic: not UTF-8 ({error})") from error


def _as_buffer(part: Any, what: str) -> memoryview:
    """A flat byte view of a message part: a zmq.Frame (its .buffer), bytes, bytearray or memoryview."""
    source = getattr(part, "buffer", part)  # zmq.Frame exposes the message memory as .buffer
    try:
        view = memoryview(source)
    except TypeError as error:
        raise WireError(f"{what}: expected bytes or a zmq.Frame, got {type(part).__name__}") from error
    if view.ndim != 1 or view.itemsize != 1:
        if not view.c_contiguous:
            raise WireError(f"{what}: a message part must be one contiguous buffer")
        view = view.cast("B")
    return view
