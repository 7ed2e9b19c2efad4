"""ZeroMQ wire format: one multipart message per frame or status report (spec: docs/wire-format.md).

    frame:  [topic, header, data]   header = msgpack map, data = raw intensity bytes (C order)
    status: [topic, header]         header = msgpack map with a "status" map

Pixels never go through msgpack (it would copy them) and nothing is ever pickled. Encoding hands the
array's own memory to ZeroMQ; decoding returns a numpy view over the received buffer (zmq.Frame with
recv_multipart(copy=False), or bytes), so a 2 MiB frame crosses the socket without a Python-level copy.
This module does not import zmq: it works on anything that exposes the buffer protocol or `.buffer`.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from sonar_realism.errors import FrameError, WireError
from sonar_realism.frames import SUPPORTED_DTYPES, SonarImage, checked_axis

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

_REQUIRED_FRAME_KEYS = frozenset({"v", "type", "seq", "stamp_ns", "frame_id", "dtype", "shape", "layout",
                                  "ranges_m", "azimuths_rad"})
_REQUIRED_STATUS_KEYS = frozenset({"status"})
_UNIFORM_AXIS_KEYS = frozenset({"start", "step", "count"})
_UINT64_END = 1 << 64  # seq, stamp_ns and sent_ns are below this
_NUMBER_TYPES = (int, float)  # exact types: msgpack decodes to nothing else, and bool must not pass as a number
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
        "ranges_m": _encode_axis(frame.ranges_m, "ranges_m"),
        "azimuths_rad": _encode_axis(frame.azimuths_rad, "azimuths_rad"),
        "intensity_scale": frame.intensity_scale,
        "meta": meta,
    }
    if provenance is not None:
        if not isinstance(provenance, Mapping):
            raise WireError("provenance", f"expected a dict, got {type(provenance).__name__}", topic)
        header["provenance"] = dict(provenance)
    return [topic_bytes, _pack_header(header, topic), memoryview(intensity).cast("B")]


def encode_status(topic: str, status: dict) -> list:
    """Parts [topic, header] of one status/heartbeat message (fields: docs/wire-format.md, "Status")."""
    topic_bytes = _encode_topic(topic)
    if not isinstance(status, Mapping):
        raise WireError("status", f"expected a dict, got {type(status).__name__}", topic)
    checked = _check_status(dict(status), topic)
    header = {"v": WIRE_VERSION, "type": STATUS_TYPE, "sent_ns": time.time_ns(), "status": checked}
    return [topic_bytes, _pack_header(header, topic)]


@dataclass(frozen=True, init=False)
class Message:
    """One received message: a frame (`body` is a SonarImage) or a status report (`body` is its status map)."""

    topic: str
    kind: str                 # FRAME_TYPE or STATUS_TYPE
    body: SonarImage | dict
    sent_ns: int | None = None  # the publisher's wall-clock send time, when it sent one

    def __init__(self, topic: str, kind: str, body: SonarImage | dict, sent_ns: int | None = None) -> None:
        # By hand, as SonarImage's: one per received message, and the generated frozen __init__ (a setattr per
        # field through object.__setattr__) cost more than the rest of a status message's decode.
        self.__dict__.update(topic=topic, kind=kind, body=body, sent_ns=sent_ns)


def decode_message(parts: Sequence[Any]) -> Message:
    """The frame or status report in one received multipart message; WireError naming topic and field if not."""
    # (recv_multipart gives a list: the exact type test spares the Sequence ABC check on every message)
    if not (type(parts) is list or isinstance(parts, Sequence)) or len(parts) not in (2, 3):
        count = len(parts) if isinstance(parts, Sequence) else type(parts).__name__
        topic = _topic_for_error(parts[0]) if isinstance(parts, Sequence) and parts else None
        raise WireError("parts", f"expected 3 parts [topic, header, data] or 2 [topic, header], got {count}", topic)
    topic = _decode_topic(parts[0])
    header = _unpack_header(parts[1], topic)
    kind = header.get("type")
    sent_ns = header.get("sent_ns")
    if sent_ns is not None and not (type(sent_ns) is int and 0 <= sent_ns < _UINT64_END):
        raise WireError("sent_ns", f"expected an unsigned 64-bit int (ns since the Unix epoch), got {sent_ns!r}",
                        topic)
    if kind == FRAME_TYPE:
        if len(parts) != 3:
            raise WireError("parts", f"a frame message has 3 parts [topic, header, data], got {len(parts)}", topic)
        return Message(topic, FRAME_TYPE, _decode_frame_body(topic, header, parts[2]), sent_ns)
    if kind == STATUS_TYPE:
        if len(parts) != 2:
            raise WireError("parts", f"a status message has 2 parts [topic, header], got {len(parts)}", topic)
        _require_keys(topic, header, _REQUIRED_STATUS_KEYS)
        status = header.get("status")
        if not isinstance(status, dict):
            raise WireError("status", f"expected a map, got {type(status).__name__}", topic)
        return Message(topic, STATUS_TYPE, _check_status(status, topic), sent_ns)
    raise WireError("type", f"expected {FRAME_TYPE!r} or {STATUS_TYPE!r}, got {kind!r}", topic)


def decode_frame(parts: Sequence[Any]) -> tuple[str, SonarImage]:
    """(topic, SonarImage) of a frame message; WireError if the message is malformed or not a frame."""
    message = decode_message(parts)
    if message.kind != FRAME_TYPE:
        raise WireError("type", f"expected a frame message, got type {message.kind!r}", message.topic)
    return message.topic, message.body


def _decode_frame_body(topic: str, header: dict, data: Any) -> SonarImage:
    # Runs once per received frame: every check is inline, and SonarImage is given values of the types it keeps.
    try:
        dtype_name, shape, layout = header["dtype"], header["shape"], header["layout"]
        seq, stamp_ns, frame_id = header["seq"], header["stamp_ns"], header["frame_id"]
        ranges, azimuths = header["ranges_m"], header["azimuths_rad"]
    except KeyError:
        _require_keys(topic, header, _REQUIRED_FRAME_KEYS)  # names the alphabetically first missing field
        raise
    dtype = WIRE_DTYPES.get(dtype_name) if type(dtype_name) is str else None
    if dtype is None:
        raise WireError("dtype", f"unknown dtype {dtype_name!r}; supported: {', '.join(sorted(WIRE_DTYPES))}", topic)
    if (type(shape) is not list or not 2 <= len(shape) <= 3
            or not all(type(n) is int and n > 0 for n in shape)):
        raise WireError("shape", f"expected [n_ranges, n_beams] or [n_samples, n_ranges, n_beams] of positive "
                                 f"ints, got {shape!r}", topic)
    if layout != LAYOUT:
        raise WireError("layout", f"expected {LAYOUT!r}, got {layout!r}", topic)
    if not (type(seq) is int and 0 <= seq < _UINT64_END):
        raise WireError("seq", f"expected an unsigned 64-bit int, got {seq!r}", topic)
    if not (type(stamp_ns) is int and 0 <= stamp_ns < _UINT64_END):
        raise WireError("stamp_ns", f"expected an unsigned 64-bit int, got {stamp_ns!r}", topic)
    buffer = _as_buffer(data, "data", topic)
    expected = math.prod(shape) * dtype.itemsize
    if buffer.nbytes != expected:
        raise WireError("data", f"expected {expected} bytes for shape {shape} of {dtype_name}, got {buffer.nbytes}",
                        topic)
    intensity = np.frombuffer(buffer, dtype=dtype).reshape(shape)  # a view over the received message
    if not dtype.isnative:
        # Byte order is settled here, once: everything downstream (models, geometry, OpenCV) sees native samples.
        intensity = intensity.astype(dtype.newbyteorder("="))
    # Read-only: over inproc the received message is the sender's own array, which a write would corrupt.
    intensity.flags.writeable = False

    meta = header.get("meta", {})
    if type(meta) is not dict:
        raise WireError("meta", f"expected a map, got {type(meta).__name__}", topic)
    provenance = header.get("provenance")
    if provenance is not None:
        if type(provenance) is not dict:
            raise WireError("provenance", f"expected a map, got {type(provenance).__name__}", topic)
        meta = {**meta, "provenance": provenance}
    try:  # a recorder writes every frame's meta as JSON: what JSON cannot hold must not get that far
        json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise WireError("meta", f"not JSON-like ({error}); meta holds maps, lists, strings, finite numbers, "
                                f"booleans and nulls", topic) from error
    scale = header.get("intensity_scale", 0.0)
    if type(scale) not in _NUMBER_TYPES:
        raise WireError("intensity_scale", f"expected a number, got {scale!r}", topic)
    try:
        return SonarImage(intensity, _decode_axis(ranges, "ranges_m", shape[-2], topic),
                          _decode_axis(azimuths, "azimuths_rad", shape[-1], topic), stamp_ns, seq, frame_id, scale,
                          meta)
    except FrameError as error:
        # FrameError messages start with the SonarImage field at fault ("intensity: NaN or inf ...").
        field, _, reason = str(error).partition(": ")
        raise WireError(field if reason else "frame", reason or str(error), topic) from error


def _encode_axis(values: np.ndarray, name: str) -> dict | bytes:
    forwarded = _FORWARDED_AXES.get(id(values))  # an id there is that array's: it is held, so alive and unique
    if forwarded is not None:
        return forwarded[1]
    explicit = np.ascontiguousarray(values, dtype=_FLOAT64_LE).tobytes()
    recent = _SENT_AXES[name]
    encoded = recent.get(explicit)
    if encoded is None:
        encoded = _uniform_form(values) or explicit
        recent.put(explicit, encoded)
    return encoded


def _uniform_form(values: np.ndarray) -> dict | None:
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
    return None


def _decode_axis(value: Any, name: str, count: int, topic: str) -> np.ndarray:
    """Axis from the uniform form {start, step, count}, float64 little-endian bytes, or a list of numbers.

    Uniform and bytes forms seen lately give the axis checked when first seen (frames.checked_axis), so a
    stream's geometry is validated once, not per frame; anything else is checked here in full.
    """
    if isinstance(value, dict):
        if value.keys() != _UNIFORM_AXIS_KEYS:
            raise WireError(name, f"a uniform axis has exactly the keys start, step, count; "
                                  f"got {sorted(map(str, value))}", topic)
        start, step, n = value["start"], value["step"], value["count"]
        if type(start) not in _NUMBER_TYPES or type(step) not in _NUMBER_TYPES:
            raise WireError(name, "start and step must be numbers", topic)
        if not isinstance(n, int) or n != count:
            raise WireError(name, f"count {n!r} does not match the shape ({count})", topic)
        key: tuple | bytes = (float(start), float(step), count)
    elif isinstance(value, bytes):
        if len(value) != 8 * count:
            raise WireError(name, f"expected {count} float64 values ({8 * count} bytes), got {len(value)} bytes",
                            topic)
        key = value
    elif isinstance(value, list):
        if len(value) != count or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in value):
            raise WireError(name, f"expected a list of {count} numbers", topic)
        return np.asarray(value, dtype=np.float64)
    else:
        raise WireError(name, f"expected {{start, step, count}}, float64 bytes or a list, got "
                              f"{type(value).__name__}", topic)
    recent = _RECEIVED_AXES[name]
    axis = recent.get(key)
    if axis is None:
        if isinstance(key, bytes):
            values = np.frombuffer(key, dtype="<f8")
        else:
            with np.errstate(all="ignore"):  # an absurd start/step gives inf/NaN, which the check rejects
                values = key[0] + key[1] * np.arange(count)
        axis = checked_axis(values, name, count)  # FrameError names the field; the caller makes it a WireError
        recent.put(key, axis)
        # How encode_frame sends this very array (read-only, shared by the stream's frames) when a node forwards
        # or relabels a received frame: found by identity, so its bytes are neither copied nor compared again.
        _remember_forwarded(axis, _uniform_form(axis) or axis.astype(_FLOAT64_LE).tobytes())
    return axis


class _RecentAxes:
    """The last few distinct axes of one name, by exact key (float64 bytes or uniform (start, step, count)).

    Compared by equality, newest first: a sonar stream sends the same geometry every frame, so the lookup is one
    memcmp. Safe across threads: readers iterate a tuple that `put` replaces whole.
    """

    def __init__(self, size: int = 8) -> None:
        self._size = size
        self._entries: tuple[tuple[Any, Any], ...] = ()

    def get(self, key: Any) -> Any:
        for known, value in self._entries:
            if known == key:
                return value
        return None

    def put(self, key: Any, value: Any) -> None:
        self._entries = ((key, value), *self._entries[: self._size - 1])


_FLOAT64_LE = np.dtype("<f8")
_AXIS_NAMES = ("ranges_m", "azimuths_rad")
_SENT_AXES = {name: _RecentAxes() for name in _AXIS_NAMES}      # explicit bytes -> the form encode_frame sends
_RECEIVED_AXES = {name: _RecentAxes() for name in _AXIS_NAMES}  # wire form -> checked read-only axis
# id(axis) -> (axis, the form encode_frame sends) for the last axes decode_frame checked; holding each array keeps
# its id from being reused. Looked up without a lock (one dict.get); changed under the lock, only for new geometry.
_FORWARDED_AXES: dict[int, tuple[np.ndarray, dict | bytes]] = {}
_FORWARDED_AXES_LOCK = threading.Lock()
_MAX_FORWARDED_AXES = 16


def _remember_forwarded(axis: np.ndarray, form: dict | bytes) -> None:
    with _FORWARDED_AXES_LOCK:
        if len(_FORWARDED_AXES) >= _MAX_FORWARDED_AXES:
            del _FORWARDED_AXES[next(iter(_FORWARDED_AXES))]  # the oldest
        _FORWARDED_AXES[id(axis)] = (axis, form)


def _check_status(status: dict, topic: str | None = None) -> dict:
    if not all(isinstance(key, str) for key in status):
        raise WireError("status", "keys must be strings", topic)
    node, state = status.get("node"), status.get("state")
    if not isinstance(node, str) or not node:
        raise WireError("status.node", f"expected a non-empty node name, got {node!r}", topic)
    if state not in STATUS_STATES:
        raise WireError("status.state", f"expected one of {', '.join(STATUS_STATES)}, got {state!r}", topic)
    for name in _STATUS_COUNTERS:
        value = status.get(name, 0)
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < 0:
            raise WireError(f"status.{name}", f"expected a non-negative int, got {value!r}", topic)
    for name in _STATUS_NUMBERS:
        value = status.get(name, 0)
        if not isinstance(value, int | float | np.number) or isinstance(value, bool) or not math.isfinite(value):
            raise WireError(f"status.{name}", f"expected a finite number, got {value!r}", topic)
    return status


def _pack_header(header: dict, topic: str) -> bytes:
    try:
        packed = _packer().pack(header)
    except (TypeError, ValueError, OverflowError) as error:
        raise WireError("header", f"cannot encode ({error}); meta, provenance and status must be JSON-like "
                                  f"(dict, list, str, int, float, bool, None, bytes)", topic) from error
    if len(packed) > MAX_HEADER_BYTES:
        _THREAD.packer = None  # its buffer grew to this size: let it go
        raise WireError("header", f"{len(packed)} bytes exceeds the {MAX_HEADER_BYTES}-byte limit; "
                                  f"keep large data out of meta/provenance", topic)
    return packed


def _packer() -> msgpack.Packer:
    """This thread's msgpack packer: making one per message costs more than packing a header. (One per thread: a
    packer's buffer must not be shared by two messages at once; it resets itself when packing fails.)"""
    packer = getattr(_THREAD, "packer", None)
    if packer is None:
        packer = _THREAD.packer = msgpack.Packer(use_bin_type=True, default=_plain_value)
    return packer


_THREAD = threading.local()


def _plain_value(value: Any) -> Any:
    """msgpack fallback for numpy scalars and small arrays that land in meta (e.g. np.float32 gains)."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot serialize {type(value).__name__}")


# Why msgpack gave up, in words a publisher can act on (several of its exceptions carry no message).
_MSGPACK_REASONS = {
    "OutOfData": "truncated: the data ends inside a value",
    "ExtraData": "bytes left over after the first value (the header must be exactly one map)",
    "FormatError": "a byte that starts no msgpack value (e.g. 0xc1)",
    "StackError": "nested too deeply",
    "UnicodeDecodeError": "a str value is not valid UTF-8 (send bytes as bin, text as str)",
}


def _unpack_header(part: Any, topic: str) -> dict:
    buffer = _as_buffer(part, "header", topic)
    if buffer.nbytes > MAX_HEADER_BYTES:
        raise WireError("header", f"{buffer.nbytes} bytes exceeds the {MAX_HEADER_BYTES}-byte limit", topic)
    if buffer.nbytes == 0:
        raise WireError("header", "empty part; expected a msgpack map", topic)
    try:
        # max_ext_len=0: msgpack refuses every extension with data in C, before it would decode the timestamp
        # extension (-1) itself; the hooks below, which name the type, run only for a header that failed.
        header = msgpack.unpackb(buffer, raw=False, ext_hook=_reject_ext, strict_map_key=True, max_ext_len=0)
    except Exception as error:  # msgpack raises many types for corrupt input; all mean "not our header"
        raise _header_error(buffer, topic, error) from error
    if not isinstance(header, dict):
        raise WireError("header", f"expected a msgpack map, got {type(header).__name__}", topic)
    version = header.get("v")
    if type(version) is not int or version != WIRE_VERSION:
        raise WireError("v", f"wire version {version!r} is not supported (this reader speaks version "
                             f"{WIRE_VERSION}); upgrade the older side", topic)
    return header


def _header_error(buffer: memoryview, topic: str, error: Exception) -> WireError:
    """The WireError for a header msgpack refused: the extension type it holds, or why it is not msgpack.
    (Unpacks again with extensions decoded and Python hooks, which name the type: only for a rejected message.)"""
    try:
        header = msgpack.unpackb(buffer, raw=False, ext_hook=_reject_ext, strict_map_key=True,
                                 object_hook=_reject_timestamps_in_map, list_hook=_reject_timestamps_in_list)
    except _ExtensionFound as found:
        hint = " (the timestamp extension: send ns since the epoch as an int)" if found.code == -1 else ""
        return WireError("header", f"msgpack extension type {found.code}{hint} is not part of the wire format", topic)
    except Exception as second:
        error = second
    else:
        if isinstance(header, msgpack.Timestamp):
            return WireError("header", "msgpack extension type -1 (timestamp) is not part of the wire format", topic)
    name = type(error).__name__
    reason = _MSGPACK_REASONS.get(name, "")
    text = "; ".join(t for t in (reason, str(error)) if t) or name
    return WireError("header", f"not valid msgpack ({name}: {text})", topic)


class _ExtensionFound(Exception):
    def __init__(self, code: int) -> None:
        self.code = code


def _reject_ext(code: int, data: bytes) -> Any:
    raise _ExtensionFound(code)


# msgpack decodes the timestamp extension (-1) itself, without calling ext_hook: catch it in its container.
# (`in map(type, ...)` runs the scan in C: these hooks run for every map and list of every header.)
def _reject_timestamps_in_map(mapping: dict) -> dict:
    if msgpack.Timestamp in map(type, mapping.values()):
        raise _ExtensionFound(-1)
    return mapping


def _reject_timestamps_in_list(items: list) -> list:
    if msgpack.Timestamp in map(type, items):
        raise _ExtensionFound(-1)
    return items


def _require_keys(topic: str, header: dict, required: frozenset[str]) -> None:
    if header.keys() >= required:
        return
    missing = sorted(required - set(header))
    if missing:
        raise WireError(missing[0], f"header is missing field(s) {', '.join(missing)}", topic)


def _encode_topic(topic: str) -> bytes:
    if not isinstance(topic, str):
        raise WireError("topic", f"expected str, got {type(topic).__name__}")
    encoded = topic.encode("utf-8")
    if len(encoded) > MAX_TOPIC_BYTES:
        raise WireError("topic", f"{len(encoded)} bytes exceeds the {MAX_TOPIC_BYTES}-byte limit")
    return encoded


def _decode_topic(part: Any) -> str:
    buffer = _as_buffer(part, "topic", None)
    if buffer.nbytes > MAX_TOPIC_BYTES:
        raise WireError("topic", f"{buffer.nbytes} bytes exceeds the {MAX_TOPIC_BYTES}-byte limit")
    try:
        return str(buffer, "utf-8")
    except UnicodeDecodeError as error:
        raise WireError("topic", f"not UTF-8 ({error})") from error


def _topic_for_error(part: Any) -> str | None:
    """The topic of a message being rejected for another reason, when it is readable."""
    try:
        return _decode_topic(part)
    except WireError:
        return None


def _as_buffer(part: Any, what: str, topic: str | None) -> memoryview:
    """A flat byte view of a message part: a zmq.Frame (its .buffer), bytes, bytearray or memoryview."""
    try:
        view = memoryview(part)  # a zmq.Frame is a buffer itself (its .buffer property costs more)
    except TypeError:
        try:
            view = memoryview(part.buffer)
        except (AttributeError, TypeError) as error:
            raise WireError(what, f"expected bytes or a zmq.Frame, got {type(part).__name__}", topic) from error
    if view.ndim != 1 or view.itemsize != 1:
        if not view.c_contiguous:
            raise WireError(what, "a message part must be one contiguous buffer", topic)
        view = view.cast("B")
    return view
