"""The one frame type that flows through everything: a polar sonar image with its geometry.

Layout: `intensity[range_bin, beam]` (row = range bin, nearest first; column = beam, left to right),
or `intensity[sample, range_bin, beam]` when a translator returns several samples of one input.
"""

from __future__ import annotations

import contextvars
import math
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sonar_realism.errors import FrameError

SUPPORTED_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.uint32), np.dtype(np.float32),
                    np.dtype(np.float64))

# Full-scale value of each integer sample width; floats are normalised to [0, 1] unless told otherwise.
DEFAULT_INTENSITY_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0,
                           np.dtype(np.uint32): 4294967295.0, np.dtype(np.float32): 1.0,
                           np.dtype(np.float64): 1.0}
_INTEGER = (int, np.integer)


@dataclass(frozen=True, eq=False, init=False)
class SonarImage:
    """A polar sonar frame.

    intensity:       array [n_ranges, n_beams] or [n_samples, n_ranges, n_beams], one of SUPPORTED_DTYPES.
                     Float frames must be finite: NaN/inf are rejected (policy: a reader that meets them
                     raises FormatError naming the file; nothing silently turns them into numbers).
    ranges_m:        range of each row's centre, metres, strictly increasing, >= 0.
    azimuths_rad:    bearing of each beam's centre, radians, strictly increasing (left to right). Oculus
                     bearing tables are not uniform, so this is per beam, never (min, max).
    stamp_ns:        acquisition time, ns since the Unix epoch (0 when unknown).
    seq:             sequence number from the source (ping id, frame counter).
    frame_id:        sensor frame name, as in ROS.
    intensity_scale: the intensity value that means full scale (255 for 8-bit, 1.0 for normalised floats).
    meta:            ping metadata, JSON-able: frequency_hz, sound_speed_mps, gain_percent,
                     range_resolution_m, vertical_aperture_rad, source, provenance, ... (None: a new empty dict)
    """

    intensity: np.ndarray
    ranges_m: np.ndarray
    azimuths_rad: np.ndarray
    stamp_ns: int = 0
    seq: int = 0
    frame_id: str = "sonar"
    intensity_scale: float = 0.0  # 0 selects the dtype's default (DEFAULT_INTENSITY_SCALE)
    meta: dict[str, Any] = field(default_factory=dict)

    def __init__(self, intensity: np.ndarray, ranges_m: Any, azimuths_rad: Any, stamp_ns: int = 0, seq: int = 0,
                 frame_id: str = "sonar", intensity_scale: float = 0.0, meta: dict[str, Any] | None = None) -> None:
        # Written by hand: the generated __init__ of a frozen dataclass sets each field through
        # object.__setattr__, which took more time than all the checks below.
        self.__dict__.update(intensity=intensity, ranges_m=ranges_m, azimuths_rad=azimuths_rad, stamp_ns=stamp_ns,
                             seq=seq, frame_id=frame_id, intensity_scale=intensity_scale,
                             meta={} if meta is None else meta)
        self._check()

    def _check(self) -> None:
        # Runs for every frame received or made (the wire decoder builds one per message): kept lean.
        intensity = self.intensity
        if not isinstance(intensity, np.ndarray):
            raise FrameError(f"intensity: expected a numpy array, got {type(intensity).__name__}")
        dtype = intensity.dtype if intensity.dtype.isnative else intensity.dtype.newbyteorder("=")
        default_scale = DEFAULT_INTENSITY_SCALE.get(dtype)
        if default_scale is None:
            raise FrameError(f"intensity: unsupported dtype {intensity.dtype}; "
                             f"supported: {', '.join(str(d) for d in SUPPORTED_DTYPES)}")
        shape = intensity.shape
        if len(shape) not in (2, 3):
            raise FrameError(f"intensity: expected [ranges, beams] or [samples, ranges, beams], got shape {shape}")
        if 0 in shape:
            raise FrameError(f"intensity: empty shape {shape}")
        if dtype.kind == "f" and intensity is not _CHECKED_INTENSITY.get() and not all_finite(intensity):
            raise FrameError("intensity: NaN or inf in a float frame (not allowed; see SonarImage docs)")

        # The checked values (a float64 axis, a Python int) are what the frame keeps.
        fields = self.__dict__
        fields["ranges_m"] = _axis(fields["ranges_m"], "ranges_m", shape[-2])
        fields["azimuths_rad"] = _axis(fields["azimuths_rad"], "azimuths_rad", shape[-1])
        for name in ("stamp_ns", "seq"):
            value = fields[name]
            if type(value) is not int:
                if not isinstance(value, _INTEGER):
                    raise FrameError(f"{name}: expected a non-negative int, got {value!r}")
                value = fields[name] = int(value)
            if value < 0:
                raise FrameError(f"{name}: expected a non-negative int, got {value!r}")
        if not isinstance(self.frame_id, str):
            raise FrameError(f"frame_id: expected str, got {type(self.frame_id).__name__}")
        scale = float(self.intensity_scale) or default_scale
        if not math.isfinite(scale) or scale <= 0:
            raise FrameError(f"intensity_scale: expected a positive finite number, got {self.intensity_scale}")
        fields["intensity_scale"] = scale
        if not isinstance(self.meta, dict) or not all(map(str.__instancecheck__, self.meta)):
            raise FrameError("meta: expected a dict with str keys")

    @property
    def n_ranges(self) -> int:
        return self.intensity.shape[-2]

    @property
    def n_beams(self) -> int:
        return self.intensity.shape[-1]

    @property
    def n_samples(self) -> int:
        """Number of samples on the leading axis (1 for a plain [ranges, beams] frame)."""
        return self.intensity.shape[0] if self.intensity.ndim == 3 else 1

    @property
    def max_range_m(self) -> float:
        return float(self.ranges_m[-1])

    @property
    def range_resolution_m(self) -> float:
        return float(np.median(np.diff(self.ranges_m))) if self.n_ranges > 1 else float(self.ranges_m[0])

    @property
    def fov_rad(self) -> float:
        return float(self.azimuths_rad[-1] - self.azimuths_rad[0])

    def normalized(self) -> np.ndarray:
        """Intensity as float32 in [0, 1] (values above full scale clipped)."""
        out = self.intensity.astype(np.float32) / np.float32(self.intensity_scale)
        return np.clip(out, 0.0, 1.0, out=out)

    def sample(self, index: int) -> SonarImage:
        """One sample of a multi-sample frame, as a plain [ranges, beams] frame."""
        if self.intensity.ndim != 3:
            raise FrameError("sample(): this frame has no sample axis")
        return self.replace(intensity=self.intensity[index])

    def replace(self, **changes: Any) -> SonarImage:
        """A copy with some fields changed, validated again; an unchanged intensity is not scanned for NaN/inf
        again (it was when this frame was made: a pass over every sample that a relabelled frame, e.g. a
        translator's output stamped with its input's seq, need not pay twice)."""
        # The fields are exactly __dict__ (frozen, set once in __init__): cheaper than dataclasses.replace.
        if "intensity" in changes:
            return type(self)(**{**self.__dict__, **changes})
        token = _CHECKED_INTENSITY.set(self.intensity)
        try:
            return type(self)(**{**self.__dict__, **changes})
        finally:
            _CHECKED_INTENSITY.reset(token)

    def same_geometry(self, other: SonarImage, atol: float = 1e-6) -> bool:
        return (self.n_ranges == other.n_ranges and self.n_beams == other.n_beams
                and np.allclose(self.ranges_m, other.ranges_m, atol=atol)
                and np.allclose(self.azimuths_rad, other.azimuths_rad, atol=atol))


# The intensity of the frame being replace()d: already checked, so its SonarImage copy skips the NaN/inf pass.
_CHECKED_INTENSITY: contextvars.ContextVar[np.ndarray | None] = contextvars.ContextVar("checked_intensity",
                                                                                       default=None)

# Per native float dtype: the unsigned int of its width and the bit pattern of +inf. A float read as that int is
# below +inf's pattern exactly when it is finite and its sign bit is clear (NaN and -0.0 included in "not").
_INF_BITS = {np.dtype(np.float32): (np.dtype(np.uint32), 0x7F800000),
             np.dtype(np.float64): (np.dtype(np.uint64), 0x7FF0000000000000)}


def all_finite(values: np.ndarray) -> bool:
    """Whether every element of a float array is finite (no NaN, no ±inf).

    One integer max over the elements' bits, without a temporary array, settles it for arrays with no negative
    element (sonar intensities): a max below +inf's bit pattern means every element is a finite float >= +0.
    Anything else (a negative element, -0.0, NaN or ±inf, a non-native byte order) is decided by the exact
    elementwise check, so the answer never differs from `np.isfinite(values).all()`.
    """
    bits = _INF_BITS.get(values.dtype)
    if bits is not None and values.size and values.view(bits[0]).max() < bits[1]:
        return True
    return bool(np.isfinite(values).all())


def checked_axis(values: Any, name: str, expected_len: int) -> np.ndarray:
    """`values` checked as a frame's `name` axis ("ranges_m" or "azimuths_rad"), as a read-only float64 copy that
    SonarImage then takes without checking it again; FrameError if it is not a valid axis.

    For geometry that repeats frame after frame (every sonar stream): the wire decoder checks each distinct axis
    once and hands the same array to every frame. The copy is this module's own, so no caller can write to it.
    """
    axis = np.array(_check_axis(values, name, expected_len))
    axis.flags.writeable = False
    with _CHECKED_AXES_LOCK:
        if len(_CHECKED_AXES) >= _MAX_CHECKED_AXES:
            del _CHECKED_AXES[next(iter(_CHECKED_AXES))]  # the oldest; it is checked again if it comes back
        # Keyed by identity and kept alive here, so the id cannot be reused by another array while listed.
        _CHECKED_AXES[(id(axis), name)] = axis
    return axis


_CHECKED_AXES: dict[tuple[int, str], np.ndarray] = {}
_CHECKED_AXES_LOCK = threading.Lock()
_MAX_CHECKED_AXES = 64  # at most 64 x 64 KiB (an 8192-value axis, the largest a header can carry) held


def _axis(values: Any, name: str, expected_len: int) -> np.ndarray:
    checked = _CHECKED_AXES.get((id(values), name))
    if checked is values and checked.shape[0] == expected_len:
        return checked
    return _check_axis(values, name, expected_len)


def _check_axis(values: Any, name: str, expected_len: int) -> np.ndarray:
    axis = np.asarray(values, dtype=np.float64)
    if axis.ndim != 1 or axis.shape[0] != expected_len:
        raise FrameError(f"{name}: expected {expected_len} values (one per "
                         f"{'range bin' if name == 'ranges_m' else 'beam'}), got shape {axis.shape}")
    if not np.isfinite(axis).all():
        raise FrameError(f"{name}: NaN or inf")
    if expected_len > 1 and not (axis[1:] > axis[:-1]).all():
        raise FrameError(f"{name}: must be strictly increasing")
    if name == "ranges_m" and axis[0] < 0:
        raise FrameError(f"ranges_m: negative range {axis[0]}")
    if name == "azimuths_rad" and max(-axis[0], axis[-1]) > math.pi:  # increasing: the ends are the extremes
        raise FrameError("azimuths_rad: bearings beyond ±180° (are they in degrees?)")
    return axis


def uniform_ranges(n_ranges: int, max_range_m: float, min_range_m: float = 0.0) -> np.ndarray:
    """Centres of `n_ranges` equal range bins between min_range_m and max_range_m."""
    step = (max_range_m - min_range_m) / n_ranges
    return min_range_m + (np.arange(n_ranges) + 0.5) * step


def uniform_azimuths(n_beams: int, fov_rad: float) -> np.ndarray:
    """Centres of `n_beams` equal beams across a symmetric field of view."""
    step = fov_rad / n_beams
    return (np.arange(n_beams) - (n_beams - 1) / 2.0) * step
