"""ROS sonar messages <-> SonarImage, without a ROS install (the `rosbags` type system).

marine_acoustic_msgs/ProjectedSonarImage is not shipped with rosbags; its definition is registered from
the published .msg text (apl-ocean-engineering/marine_msgs, marine_acoustic_msgs 2.x, BSD-3-Clause; field
lines only, comments dropped). A bag that carries its own definition (every ROS 1 bag and MCAP file does)
is decoded with that one.

Conventions where the .msg comments leave room, taken from the published drivers (docs/formats.md):
- sample order: range-major, `data[(range_bin * n_beams + beam) * itemsize]`, as the APL Oculus driver writes
  and sonar_image_proc reads (the comment says "row-major (beam_index major)");
- beam direction: azimuth θ (positive to the right of the image, Oculus bearing sign) is the unit vector
  (x, y, z) = (0, -sin θ, cos θ), read back as atan2(-y, z): again the APL driver and sonar_image_proc. A
  right-handed reading of the comment (X up, Z forward, so Y starboard) would put a starboard beam at +y.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from sonar_realism.errors import FormatError, UnsupportedFormatError
from sonar_realism.frames import SonarImage
from sonar_realism.io.common import build_frame, json_default

PROJECTED_SONAR_IMAGE = "marine_acoustic_msgs/msg/ProjectedSonarImage"
LEGACY_PROJECTED_SONAR_IMAGE = "acoustic_msgs/msg/ProjectedSonarImage"  # the package's name before 2.0
IMAGE = "sensor_msgs/msg/Image"
STRING = "std_msgs/msg/String"
SONAR_TYPES = (PROJECTED_SONAR_IMAGE, LEGACY_PROJECTED_SONAR_IMAGE, IMAGE)

_MARINE_ACOUSTIC_MSGS = {
    "marine_acoustic_msgs/msg/PingInfo": """
float32 frequency
float32 sound_speed
float32[] tx_beamwidths
float32[] rx_beamwidths
""",
    "marine_acoustic_msgs/msg/SonarImageData": """
bool is_bigendian
uint32 DTYPE_UINT8 = 0
uint32 DTYPE_INT8 = 1
uint32 DTYPE_UINT16 = 2
uint32 DTYPE_INT16 = 3
uint32 DTYPE_UINT32 = 4
uint32 DTYPE_INT32 = 5
uint32 DTYPE_UINT64 = 6
uint32 DTYPE_INT64 = 7
uint32 DTYPE_FLOAT32 = 8
uint32 DTYPE_FLOAT64 = 9
uint32 dtype
uint32 beam_count
uint8[] data
""",
    PROJECTED_SONAR_IMAGE: """
std_msgs/Header header
PingInfo ping_info
geometry_msgs/Vector3[] beam_directions
float32[] ranges
SonarImageData image
""",
}

# SonarImageData.dtype code -> numpy dtype of the samples.
SAMPLE_DTYPES = {0: np.dtype(np.uint8), 1: np.dtype(np.int8), 2: np.dtype(np.uint16), 3: np.dtype(np.int16),
                 4: np.dtype(np.uint32), 5: np.dtype(np.int32), 6: np.dtype(np.uint64), 7: np.dtype(np.int64),
                 8: np.dtype(np.float32), 9: np.dtype(np.float64)}
_DTYPE_CODES = {dtype: code for code, dtype in SAMPLE_DTYPES.items()}
# sensor_msgs/Image encodings that are one intensity channel.
IMAGE_ENCODINGS = {"mono8": np.dtype(np.uint8), "8UC1": np.dtype(np.uint8), "mono16": np.dtype(np.uint16),
                   "16UC1": np.dtype(np.uint16), "32FC1": np.dtype(np.float32), "64FC1": np.dtype(np.float64)}
_EXACT_FLOAT64_INT = 2**53


def typestore_for(definitions: dict[str, str], ros1: bool) -> Typestore:
    """A store that decodes a bag's types: the bag's own definitions (msgtype -> ros1msg/ros2msg text with its
    dependencies) first, then the distribution's standard types, then our marine_acoustic_msgs for what the
    bag does not define."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for msgtype, text in definitions.items():
        if not text.strip():
            continue
        try:
            types.update(get_types_from_msg(text, msgtype))
        except Exception as exc:  # rosbags raises several parser errors: each means an unusable definition
            raise FormatError(msgtype, "definition", f"cannot parse the bag's message definition ({exc})") from exc
    types.update({name: fields for name, fields in _marine_types().items() if name not in types})
    store.register({name: fields for name, fields in types.items() if name not in store.fielddefs})
    return store


@cache
def _marine_types() -> dict[str, Any]:
    types: dict[str, Any] = {}
    for name, text in _MARINE_ACOUSTIC_MSGS.items():
        types.update(get_types_from_msg(text, name))
    return types


@dataclass(frozen=True)
class FrameInfo:
    """What ProjectedSonarImage cannot hold, written by us beside each message on `<topic>/frame_info`
    (std_msgs/String JSON) so that our own files read back exactly."""

    seq: int
    intensity_scale: float
    meta: dict[str, Any]
    sample: int = 0
    samples: int = 1
    ranges_m: list[float] | None = None      # only when the geometry changed since the previous frame
    azimuths_rad: list[float] | None = None

    def to_json(self) -> str:
        fields = {key: value for key, value in self.__dict__.items() if value is not None}
        return json.dumps(fields, allow_nan=False, default=json_default)

    @staticmethod
    def from_json(text: str, source: str) -> FrameInfo:
        try:
            fields = json.loads(text)
            return FrameInfo(**fields)
        except (json.JSONDecodeError, TypeError) as exc:
            raise FormatError(source, "frame_info", f"not a frame info record ({exc})") from exc


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def sonar_image_to_frame(message: Any, source: str, seq: int) -> SonarImage:
    """A ProjectedSonarImage as a SonarImage: every sample value kept (integer types SonarImage does not hold
    become the float type that represents them exactly; meta["ros_sample_dtype"] says so)."""
    n_beams = len(message.beam_directions)
    ranges = np.asarray(message.ranges, dtype=np.float64)
    image = message.image
    if image.beam_count not in (0, n_beams):  # 0: writers before beam_count existed
        raise FormatError(source, "image.beam_count", f"{image.beam_count}, but {n_beams} beam_directions")
    if image.dtype not in SAMPLE_DTYPES:
        raise UnsupportedFormatError(source, "image.dtype", f"unknown sample type code {image.dtype}")
    dtype = SAMPLE_DTYPES[image.dtype].newbyteorder(">" if image.is_bigendian else "<")
    data = np.asarray(image.data, dtype=np.uint8)
    expected = ranges.size * n_beams * dtype.itemsize
    if data.size != expected:
        raise FormatError(source, "image.data", f"{data.size} bytes for {ranges.size} ranges x {n_beams} beams "
                                                f"of {dtype.name} ({expected} bytes)")
    samples = data.view(dtype).reshape(ranges.size, n_beams)
    intensity, scale, converted = _supported_samples(samples, source)
    directions = np.array([(d.x, d.y, d.z) for d in message.beam_directions], dtype=np.float64).reshape(-1, 3)
    azimuths = np.arctan2(-directions[:, 1], directions[:, 2])
    info = message.ping_info
    meta: dict[str, Any] = {"source": source}
    if info.frequency:
        meta["frequency_hz"] = float(info.frequency)
    if info.sound_speed:
        meta["sound_speed_mps"] = float(info.sound_speed)
    if len(info.tx_beamwidths):
        meta["vertical_aperture_rad"] = float(np.median(info.tx_beamwidths))
    if converted:
        meta["ros_sample_dtype"] = converted
    header = message.header
    return build_frame(source, intensity=intensity, ranges_m=ranges, azimuths_rad=azimuths,
                  stamp_ns=stamp_ns(header), seq=int(getattr(header, "seq", seq)), frame_id=header.frame_id,
                  intensity_scale=scale, meta=meta)


def _supported_samples(samples: np.ndarray, source: str) -> tuple[np.ndarray, float, str]:
    """(intensity in a SonarImage dtype, full scale, the message's dtype name when converted)."""
    native = samples.astype(samples.dtype.newbyteorder("="), copy=True)
    kind, size = native.dtype.kind, native.dtype.itemsize
    if kind == "f" and not np.isfinite(native).all():
        raise FormatError(source, "image.data", "NaN or inf samples (rejected; see docs/formats.md)")
    if kind == "u" and size <= 4 or kind == "f":
        return native, 0.0, ""
    full_scale = float(np.iinfo(native.dtype).max)
    if size <= 2:
        return native.astype(np.float32), full_scale, native.dtype.name
    if np.abs(native.astype(np.float64)).max(initial=0) > _EXACT_FLOAT64_INT:
        raise UnsupportedFormatError(source, "image.data", f"{native.dtype.name} samples beyond 2^53 cannot be "
                                                           "held exactly")
    return native.astype(np.float64), full_scale, native.dtype.name


def frame_to_sonar_image(store: Typestore, frame: SonarImage, sample: int | None = None) -> Any:
    """One [ranges, beams] plane of `frame` as a ProjectedSonarImage message."""
    types = store.types
    intensity = frame.intensity if sample is None else frame.intensity[sample]
    dtype = intensity.dtype.newbyteorder("=")
    header = _header(store, frame)
    directions = [types["geometry_msgs/msg/Vector3"](x=0.0, y=-math.sin(a), z=math.cos(a))
                  for a in frame.azimuths_rad]
    meta = frame.meta
    aperture = meta.get("vertical_aperture_rad")
    ping_info = types["marine_acoustic_msgs/msg/PingInfo"](
        frequency=float(meta.get("frequency_hz") or 0.0), sound_speed=float(meta.get("sound_speed_mps") or 0.0),
        tx_beamwidths=np.full(frame.n_beams if aperture else 0, aperture or 0.0, np.float32),
        rx_beamwidths=np.zeros(0, np.float32))
    data = np.ascontiguousarray(intensity, dtype=dtype.newbyteorder("<")).view(np.uint8).reshape(-1)
    image = types["marine_acoustic_msgs/msg/SonarImageData"](is_bigendian=False, dtype=_DTYPE_CODES[dtype],
                                                            beam_count=frame.n_beams, data=data)
    return types[PROJECTED_SONAR_IMAGE](header=header, ping_info=ping_info, beam_directions=directions,
                                        ranges=frame.ranges_m.astype(np.float32), image=image)


def fan_image_message(store: Typestore, frame: SonarImage, width_px: int) -> Any:
    """The frame (its first sample) drawn as a fan, mono8, apex at the bottom: what a viewer shows."""
    from sonar_realism.geometry import polar_to_fan

    plane = frame if frame.intensity.ndim == 2 else frame.sample(0)
    fan = polar_to_fan(plane.replace(intensity=plane.normalized()), width_px)
    pixels = np.clip(np.rint(fan * 255.0), 0, 255).astype(np.uint8)
    return store.types[IMAGE](header=_header(store, frame), height=pixels.shape[0], width=pixels.shape[1],
                              encoding="mono8", is_bigendian=0, step=pixels.shape[1], data=pixels.reshape(-1))


def string_message(store: Typestore, text: str) -> Any:
    return store.types[STRING](data=text)


def _header(store: Typestore, frame: SonarImage) -> Any:
    types = store.types
    seconds, nanoseconds = divmod(frame.stamp_ns, 1_000_000_000)
    stamp = types["builtin_interfaces/msg/Time"](sec=seconds, nanosec=nanoseconds)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame.frame_id)


def image_pixels(message: Any, source: str) -> np.ndarray:
    """The [rows, cols] intensity array of a one-channel sensor_msgs/Image; UnsupportedFormatError otherwise."""
    dtype = IMAGE_ENCODINGS.get(message.encoding)
    if dtype is None:
        raise UnsupportedFormatError(source, "encoding", f"{message.encoding!r} is not one intensity channel "
                                                         f"(mapped: {', '.join(IMAGE_ENCODINGS)})")
    dtype = dtype.newbyteorder(">" if message.is_bigendian else "<")
    row_bytes = message.width * dtype.itemsize
    data = np.asarray(message.data, dtype=np.uint8)
    if message.step < row_bytes or data.size < message.step * message.height or message.height * message.width == 0:
        raise FormatError(source, "data", f"{data.size} bytes, step {message.step}, for {message.height} x "
                                          f"{message.width} {message.encoding}")
    rows = data[: message.step * message.height].reshape(message.height, message.step)[:, :row_bytes]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(message.height, message.width)
    return pixels.astype(dtype.newbyteorder("="), copy=True)
