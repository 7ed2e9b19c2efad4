"""NPZ recordings: one geometry, a stack of frames, streamed in both directions.

Arrays (docs/formats.md):
    intensity      [n_frames, n_ranges, n_beams] or [n_frames, n_samples, n_ranges, n_beams]
                   ([n_ranges, n_beams] alone is one frame)
    ranges_m       [n_ranges]            azimuths_rad  [n_beams]
    stamps_ns      [n_frames] int64      (optional, default 0)
    seq            [n_frames] int64      (optional, default 0, 1, 2, ...)
    meta_json      0-d str (optional): JSON {"frame_id": str, "intensity_scale": float, "meta": [dict per frame]}

Reading walks the `intensity` member of the zip one frame at a time (no full load), so a recording
larger than memory still reads. Writing spools frames to a temporary file and then copies them into the
zip, because the .npy header must state the frame count before the data.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from sonar_realism.errors import FormatError, FrameError
from sonar_realism.frames import SonarImage
from sonar_realism.io.common import build_frame, json_default
from sonar_realism.io.report import ReadReport

ZIP_MAGIC = b"PK\x03\x04"
_KNOWN_ARRAYS = {"intensity", "ranges_m", "azimuths_rad", "stamps_ns", "seq", "meta_json"}
_META_KEYS = {"frame_id", "intensity_scale", "meta"}


def read_npz(path: str | Path, report: ReadReport) -> Iterator[SonarImage]:
    path = Path(path)
    source = str(path)
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile as exc:
        raise FormatError(source, "zip", f"not a readable NPZ ({exc})") from exc
    with archive:
        members = {Path(name).stem: name for name in archive.namelist() if name.endswith(".npy")}
        for extra in sorted(set(members) - _KNOWN_ARRAYS):
            report.skip(f"npz array {extra!r}")
        for required in ("intensity", "ranges_m", "azimuths_rad"):
            if required not in members:
                raise FormatError(source, required, "array missing")
        ranges = _small_array(archive, members["ranges_m"], source, "ranges_m")
        azimuths = _small_array(archive, members["azimuths_rad"], source, "azimuths_rad")
        with archive.open(members["intensity"]) as stream:
            shape, dtype = _read_npy_header(stream, source)
            if len(shape) < 2 or len(shape) > 4:
                raise FormatError(source, "intensity", f"expected 2 to 4 dimensions, got shape {shape}")
            frame_shape = shape[1:] if len(shape) >= 3 else shape
            n_frames = shape[0] if len(shape) >= 3 else 1
            stamps = _per_frame(archive, members, "stamps_ns", n_frames, source, np.zeros(n_frames, np.int64))
            seqs = _per_frame(archive, members, "seq", n_frames, source, np.arange(n_frames, dtype=np.int64))
            frame_id, scale, metas = _read_meta(archive, members, n_frames, source)
            frame_bytes = math.prod(frame_shape) * dtype.itemsize
            for index in range(n_frames):
                payload = stream.read(frame_bytes)
                if len(payload) != frame_bytes:
                    raise FormatError(source, "intensity", f"data ends inside frame {index} of {n_frames}")
                intensity = np.frombuffer(payload, dtype=dtype).reshape(frame_shape)
                intensity = intensity.astype(dtype.newbyteorder("="), copy=True)
                if intensity.dtype.kind == "f" and not np.isfinite(intensity).all():
                    raise FormatError(source, "intensity", f"NaN or inf in frame {index} (rejected)")
                frame = build_frame(source, intensity=intensity, ranges_m=ranges, azimuths_rad=azimuths,
                                    stamp_ns=int(stamps[index]), seq=int(seqs[index]), frame_id=frame_id,
                                    intensity_scale=scale, meta=metas[index])
                report.frames += 1
                yield frame


def _read_npy_header(stream: IO[bytes], source: str) -> tuple[tuple[int, ...], np.dtype]:
    try:
        version = np.lib.format.read_magic(stream)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran_order, dtype = read_header(stream)
    except ValueError as exc:
        raise FormatError(source, "intensity", f"bad .npy header ({exc})") from exc
    if fortran_order:
        raise FormatError(source, "intensity", "Fortran-ordered array (write it C-ordered)")
    if dtype.hasobject:
        raise FormatError(source, "intensity", "object arrays are not sonar frames")
    return tuple(shape), dtype


def _small_array(archive: zipfile.ZipFile, member: str, source: str, name: str) -> np.ndarray:
    with archive.open(member) as stream:
        try:
            return np.lib.format.read_array(stream, allow_pickle=False)
        except ValueError as exc:
            raise FormatError(source, name, f"cannot decode ({exc})") from exc


def _per_frame(archive: zipfile.ZipFile, members: dict[str, str], name: str, n_frames: int, source: str,
               default: np.ndarray) -> np.ndarray:
    if name not in members:
        return default
    values = _small_array(archive, members[name], source, name)
    if values.shape != (n_frames,) or values.dtype.kind not in "iu":
        raise FormatError(source, name, f"expected {n_frames} integers, got {values.dtype} {values.shape}")
    if (values < 0).any():
        raise FormatError(source, name, "negative values")
    return values


def _read_meta(archive: zipfile.ZipFile, members: dict[str, str], n_frames: int,
               source: str) -> tuple[str, float, list[dict[str, Any]]]:
    if "meta_json" not in members:
        return "sonar", 0.0, [{} for _ in range(n_frames)]
    text = _small_array(archive, members["meta_json"], source, "meta_json")
    try:
        data = json.loads(str(text.item()))
    except (json.JSONDecodeError, ValueError) as exc:
        raise FormatError(source, "meta_json", f"not JSON ({exc})") from exc
    if not isinstance(data, dict) or set(data) - _META_KEYS:
        raise FormatError(source, "meta_json", f"expected an object with keys among {sorted(_META_KEYS)}")
    metas = data.get("meta", [{} for _ in range(n_frames)])
    if isinstance(metas, dict):
        metas = [dict(metas) for _ in range(n_frames)]
    if not isinstance(metas, list) or len(metas) != n_frames or not all(isinstance(m, dict) for m in metas):
        raise FormatError(source, "meta_json.meta", f"expected one object per frame ({n_frames})")
    frame_id = data.get("frame_id", "sonar")
    scale = data.get("intensity_scale", 0.0)
    if not isinstance(frame_id, str):
        raise FormatError(source, "meta_json.frame_id", "expected a string")
    if isinstance(scale, bool) or not isinstance(scale, int | float):
        raise FormatError(source, "meta_json.intensity_scale", "expected a number")
    return frame_id, float(scale), metas


def write_npz(frames: Iterable[SonarImage], path: str | Path) -> int:
    """Write frames sharing one geometry, dtype, frame_id and scale into `path` (.npz); returns the count."""
    path = Path(path)
    first: SonarImage | None = None
    stamps: list[int] = []
    seqs: list[int] = []
    metas: list[dict[str, Any]] = []
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=path.parent) as spool:
        for index, frame in enumerate(frames):
            if first is None:
                first = frame
            else:
                _check_same_layout(first, frame, index)
            spool.write(np.ascontiguousarray(frame.intensity, dtype=first.intensity.dtype.newbyteorder("=")).tobytes())
            stamps.append(frame.stamp_ns)
            seqs.append(frame.seq)
            metas.append(frame.meta)
        if first is None:
            raise FrameError("write_frames: no frames to write (an NPZ needs at least one for its geometry)")
        meta_text = json.dumps({"frame_id": first.frame_id, "intensity_scale": first.intensity_scale, "meta": metas},
                               default=json_default, allow_nan=False)
        shape = (len(stamps), *first.intensity.shape)
        dtype = first.intensity.dtype.newbyteorder("=")
        temporary = path.with_name(path.name + ".tmp")
        with zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as archive:
            with archive.open("intensity.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array_header_2_0(member, {"descr": np.lib.format.dtype_to_descr(dtype),
                                                              "fortran_order": False, "shape": shape})
                spool.seek(0)
                shutil.copyfileobj(spool, member, length=1 << 22)
            _write_small(archive, "ranges_m", first.ranges_m)
            _write_small(archive, "azimuths_rad", first.azimuths_rad)
            _write_small(archive, "stamps_ns", np.asarray(stamps, dtype=np.int64))
            _write_small(archive, "seq", np.asarray(seqs, dtype=np.int64))
            _write_small(archive, "meta_json", np.asarray(meta_text))
        temporary.replace(path)
    return len(stamps)


def _check_same_layout(first: SonarImage, frame: SonarImage, index: int) -> None:
    if frame.intensity.shape != first.intensity.shape or frame.intensity.dtype != first.intensity.dtype:
        raise FrameError(f"write_frames: frame {index} is {frame.intensity.dtype}{list(frame.intensity.shape)}, "
                         f"frame 0 {first.intensity.dtype}{list(first.intensity.shape)}; an NPZ holds one "
                         "shape and dtype (write a frames folder instead)")
    if not (np.array_equal(first.ranges_m, frame.ranges_m) and np.array_equal(first.azimuths_rad, frame.azimuths_rad)):
        raise FrameError(f"write_frames: frame {index} has a different geometry from frame 0; an NPZ holds one "
                         "geometry (write a frames folder instead)")
    if frame.frame_id != first.frame_id or frame.intensity_scale != first.intensity_scale:
        raise FrameError(f"write_frames: frame {index} has a different frame_id or intensity_scale from frame 0")


def _write_small(archive: zipfile.ZipFile, name: str, array: np.ndarray) -> None:
    with archive.open(f"{name}.npy", "w") as member:
        np.lib.format.write_array(member, array, allow_pickle=False)

