"""Frames folders (what `write_frames` writes) and plain folders of PNG/TIFF polar images.

Frames folder (docs/formats.md):

    DIR/frames.jsonl            header line, then one JSON line per frame, appended as frames are written
    DIR/frames/000000.png       8/16-bit [ranges, beams] frames: person-viewable, lossless PNG
    DIR/frames/000001.npy       everything else (float, uint32, multi-sample [samples, ranges, beams])
    DIR/geometry/<digest>.json  ranges_m and azimuths_rad, stored once per distinct geometry

Each index line is written after its image and geometry files are complete, so a folder that is still
being written (or whose writer died) reads back every frame whose line is complete. Everything else in
DIR (masks/, manifest.json, contact sheets) belongs to someone else and is ignored.

Plain image folders: every PNG/TIFF file (chosen by content, not extension) is a polar frame, rows =
range bins nearest first. Geometry comes from a JSON sidecar: `<image stem>.json` beside the image,
merged over a folder-wide `sonar.json` (`sonar_realism.io.common`). Images that look like a Cartesian
fan (zero outside a sector) or whose sidecar says `"kind": "fan"` are converted to polar by `sonar_realism.io.fan`.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sonar_realism.errors import FormatError, FrameError
from sonar_realism.frames import SonarImage
from sonar_realism.io import fan
from sonar_realism.io.common import ImageSidecar, build_frame, json_default, load_sidecar, polar_frame
from sonar_realism.io.report import ReadReport

INDEX_NAME = "frames.jsonl"
FORMAT_NAME = "sonar-realism-frames"
FORMAT_VERSION = 1

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
TIFF_MAGICS = (b"II*\x00", b"MM\x00*")
_PNG_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16))
_INDEX_KEYS = {"file", "geometry", "dtype", "shape", "stamp_ns", "seq", "frame_id", "intensity_scale", "meta"}


def natural_key(path: Path) -> list[Any]:
    """Sort key so that img-2 comes before img-10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


# ---------------------------------------------------------------------------------------------- frames folders


def is_frames_folder(path: Path) -> bool:
    return (path / INDEX_NAME).is_file()


def write_frames_folder(frames: Iterable[SonarImage], path: str | Path, append: bool = False) -> int:
    """Write `frames` into folder `path` one by one (never holding more than one); returns the count written.

    An index already in `path` is replaced, and the image and geometry files it listed are removed; other
    files stay. With `append`, frames are added after those the index lists instead (a recorder restarted within
    its launch goes on with its recording); a last line cut short by a crash is dropped first.
    """
    root = Path(path)
    if root.exists() and not root.is_dir():
        raise FormatError(str(root), "path", "exists and is not a folder (name it .npz to write an NPZ)")
    (root / "frames").mkdir(parents=True, exist_ok=True)
    (root / "geometry").mkdir(exist_ok=True)
    first = listed_frames(root) if append and is_frames_folder(root) else None
    if first is None:
        _remove_previous_frames(root)
    written_geometries: set[str] = set()
    count = 0
    with open(root / INDEX_NAME, "a" if first is not None else "w", encoding="utf-8") as index:
        if first is None:
            index.write(json.dumps({"format": FORMAT_NAME, "version": FORMAT_VERSION}) + "\n")
            index.flush()
        for count, frame in enumerate(frames, start=1):
            line = _write_one(root, (first or 0) + count - 1, frame, written_geometries)
            index.write(json.dumps(line, default=json_default, allow_nan=False) + "\n")
            index.flush()
    return count


def last_seq(path: str | Path) -> int | None:
    """The seq of the last frame a frames folder's index lists in full (None: no folder or no frame)."""
    index_path = Path(path) / INDEX_NAME
    if not index_path.is_file():
        return None
    lines = index_path.read_bytes().split(b"\n")[1:-1]  # after the header; the last piece is cut or empty
    for line in reversed(lines):
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(entry, dict) and type(entry.get("seq")) is int:
            return entry["seq"]
    return None


def listed_frames(root: str | Path) -> int:
    """The number of frames a frames folder's index lists, after cutting a last line a crash left unfinished."""
    index_path = Path(root) / INDEX_NAME
    content = index_path.read_bytes()
    whole = content[: content.rfind(b"\n") + 1]
    if len(whole) != len(content):
        with open(index_path, "r+b") as index:
            index.truncate(len(whole))
    return max(whole.count(b"\n") - 1, 0)


def _write_one(root: Path, number: int, frame: SonarImage, written_geometries: set[str]) -> dict[str, Any]:
    if not isinstance(frame, SonarImage):
        raise FrameError(f"write_frames: frame {number} is a {type(frame).__name__}, not a SonarImage")
    try:
        json.dumps(frame.meta, default=json_default, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise FrameError(f"meta: frame {number} meta is not JSON-able ({exc})") from exc
    geometry = {"ranges_m": frame.ranges_m.tolist(), "azimuths_rad": frame.azimuths_rad.tolist()}
    geometry_text = json.dumps(geometry)
    digest = hashlib.sha1(geometry_text.encode()).hexdigest()[:16]
    geometry_name = f"geometry/{digest}.json"
    if digest not in written_geometries:
        _atomic_write_bytes(root / geometry_name, geometry_text.encode())
        written_geometries.add(digest)

    intensity = frame.intensity.astype(frame.intensity.dtype.newbyteorder("="), copy=False)
    if intensity.ndim == 2 and intensity.dtype in _PNG_DTYPES:
        file_name = f"frames/{number:06d}.png"
        ok, encoded = cv2.imencode(".png", intensity)
        if not ok:
            raise FormatError(str(root / file_name), "intensity", "PNG encoding failed")
        payload = encoded.tobytes()
    else:
        file_name = f"frames/{number:06d}.npy"
        payload = _npy_bytes(intensity)
    _atomic_write_bytes(root / file_name, payload)
    return {"file": file_name, "geometry": geometry_name, "dtype": intensity.dtype.name,
            "shape": list(intensity.shape), "stamp_ns": frame.stamp_ns, "seq": frame.seq,
            "frame_id": frame.frame_id, "intensity_scale": frame.intensity_scale, "meta": frame.meta}


def _npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(array), allow_pickle=False)
    return buffer.getvalue()


def _atomic_write_bytes(target: Path, payload: bytes) -> None:
    temporary = target.with_name(target.name + ".tmp")
    temporary.write_bytes(payload)
    os.replace(temporary, target)


def _remove_previous_frames(root: Path) -> None:
    index_path = root / INDEX_NAME
    if not index_path.is_file():
        return
    with open(index_path, encoding="utf-8") as index:
        for line in index:
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            if not isinstance(entry, dict):
                continue
            for name in (entry.get("file"), entry.get("geometry")):
                if isinstance(name, str) and re.fullmatch(r"frames/\d{6}\.(png|npy)|geometry/[0-9a-f]{16}\.json", name):
                    (root / name).unlink(missing_ok=True)
    index_path.unlink()


def read_frames_folder(path: str | Path, report: ReadReport) -> Iterator[SonarImage]:
    """Frames of a folder written by write_frames, streamed in write order."""
    root = Path(path)
    index_path = root / INDEX_NAME
    geometries: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    with open(index_path, encoding="utf-8") as index:
        header_text = index.readline()
        try:
            header = json.loads(header_text)
        except json.JSONDecodeError as exc:
            raise FormatError(str(index_path), "header", f"not JSON ({exc.msg})") from exc
        if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
            raise FormatError(str(index_path), "header.format", f"expected {FORMAT_NAME!r}")
        if header.get("version") != FORMAT_VERSION:
            raise FormatError(str(index_path), "header.version",
                              f"version {header.get('version')!r} (this reader knows {FORMAT_VERSION})")
        for line_number, line in enumerate(index, start=2):
            if not line.endswith("\n"):
                # The writer appends whole lines; a partial one means it was interrupted mid-frame.
                report.problem(f"{index_path}:{line_number}: incomplete last line (writer interrupted?)")
                break
            where = f"{index_path}:{line_number}"
            entry = _parse_index_line(line, where)
            geometry = geometries.get(entry["geometry"])
            if geometry is None:
                geometry = _read_geometry(root, entry["geometry"], where)
                geometries[entry["geometry"]] = geometry
            intensity = _read_intensity(root, entry, where)
            frame = build_frame(root / entry["file"], intensity=intensity, ranges_m=geometry[0],
                                azimuths_rad=geometry[1], stamp_ns=entry["stamp_ns"], seq=entry["seq"],
                                frame_id=entry["frame_id"], intensity_scale=entry["intensity_scale"],
                                meta=entry["meta"])
            report.frames += 1
            yield frame


def _parse_index_line(line: str, where: str) -> dict[str, Any]:
    try:
        entry = json.loads(line)
    except json.JSONDecodeError as exc:
        raise FormatError(where, "line", f"not JSON ({exc.msg})") from exc
    if not isinstance(entry, dict):
        raise FormatError(where, "line", "expected a JSON object")
    unknown = sorted(set(entry) - _INDEX_KEYS)
    missing = sorted(_INDEX_KEYS - set(entry))
    if unknown:
        raise FormatError(where, unknown[0], f"unknown key(s) {', '.join(unknown)}")
    if missing:
        raise FormatError(where, missing[0], f"missing key(s) {', '.join(missing)}")
    for key in ("file", "geometry"):
        value = entry[key]
        if not isinstance(value, str) or ".." in Path(value).parts or Path(value).is_absolute():
            raise FormatError(where, key, f"expected a relative path inside the folder, got {value!r}")
    if not isinstance(entry["shape"], list) or not all(isinstance(n, int) for n in entry["shape"]):
        raise FormatError(where, "shape", f"expected a list of ints, got {entry['shape']!r}")
    if not isinstance(entry["meta"], dict):
        raise FormatError(where, "meta", "expected a JSON object")
    return entry


def _read_geometry(root: Path, name: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    path = root / name
    try:
        geometry = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise FormatError(str(path), "geometry", f"missing (listed at {where})") from exc
    except json.JSONDecodeError as exc:
        raise FormatError(str(path), "geometry", f"not JSON ({exc.msg})") from exc
    if not isinstance(geometry, dict) or set(geometry) != {"ranges_m", "azimuths_rad"}:
        raise FormatError(str(path), "geometry", "expected exactly the keys ranges_m and azimuths_rad")
    return np.asarray(geometry["ranges_m"], dtype=np.float64), np.asarray(geometry["azimuths_rad"], dtype=np.float64)


def _read_intensity(root: Path, entry: dict[str, Any], where: str) -> np.ndarray:
    path = root / entry["file"]
    try:
        payload = path.read_bytes()
    except FileNotFoundError as exc:
        raise FormatError(str(path), "file", f"missing (listed at {where})") from exc
    if path.suffix == ".png":
        intensity = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED)
        if intensity is None:
            raise FormatError(str(path), "png", "cannot decode (corrupt or truncated PNG)")
    elif path.suffix == ".npy":
        intensity = _load_npy(payload, path)
    else:
        raise FormatError(where, "file", f"unknown image kind {path.suffix!r}")
    if intensity.dtype.name != entry["dtype"]:
        raise FormatError(str(path), "dtype", f"file holds {intensity.dtype.name}, index says {entry['dtype']}")
    if list(intensity.shape) != entry["shape"]:
        raise FormatError(str(path), "shape", f"file holds {list(intensity.shape)}, index says {entry['shape']}")
    return intensity


def _load_npy(payload: bytes, path: Path) -> np.ndarray:
    try:
        return np.load(io.BytesIO(payload), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise FormatError(str(path), "npy", f"cannot decode ({exc})") from exc


# ---------------------------------------------------------------------------------------------- plain image folders


def read_image_file(path: Path, report: ReadReport, position: int = 0) -> Iterator[SonarImage]:
    """Frames of one PNG or TIFF (a multi-page TIFF gives one frame per page). `position` numbers
    frames of a folder when the sidecar gives no seq."""
    sidecar, sidecar_source = load_sidecar(path)
    for page_number, image in enumerate(_decode_pages(path)):
        intensity, colour_note = _to_single_channel(image, path)
        seq = position + page_number if sidecar is None or sidecar.seq is None else sidecar.seq + page_number
        meta: dict[str, Any] = {"source": path.name}
        if colour_note:
            meta["colour_converted"] = colour_note
        report.frames += 1
        yield image_to_frame(intensity, path, sidecar, sidecar_source, seq, meta)


def image_to_frame(intensity: np.ndarray, path: Path, sidecar: ImageSidecar | None, sidecar_source: str, seq: int,
                   meta: dict[str, Any]) -> SonarImage:
    """One [rows, cols] image as a frame: a fan (the sidecar says so, or it looks like one) or a polar image."""
    if sidecar is not None and sidecar.meta:
        meta = {**meta, **sidecar.meta}
    kind = sidecar.kind if sidecar is not None else None
    detected = fan.detect_fan(intensity) if kind != "polar" else None
    if kind == "fan" or (kind is None and detected is not None):
        return fan.fan_image_to_frame(intensity, path, sidecar, sidecar_source, seq, meta, detected)
    return polar_frame(intensity, path, sidecar, sidecar_source, seq, meta)


def _decode_pages(path: Path) -> list[np.ndarray]:
    payload = path.read_bytes()
    if payload.startswith(PNG_MAGIC):
        image = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise FormatError(str(path), "png", "cannot decode (corrupt or truncated PNG)")
        return [image]
    ok, pages = cv2.imdecodemulti(np.frombuffer(payload, np.uint8), cv2.IMREAD_UNCHANGED)
    if not ok or not pages:
        raise FormatError(str(path), "tiff", "cannot decode (corrupt or unsupported TIFF)")
    return list(pages)


def _to_single_channel(image: np.ndarray, path: Path) -> tuple[np.ndarray, str]:
    """Grey images as they are; R=G=B colour images (as exported by many tools) lose the copies.
    True colour (a colour map) is converted to luma and says so in meta."""
    if image.ndim == 2:
        return image, ""
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise FormatError(str(path), "channels", f"unsupported image shape {image.shape}")
    colour = image[:, :, :3]
    if (colour[:, :, 0] == colour[:, :, 1]).all() and (colour[:, :, 0] == colour[:, :, 2]).all():
        return np.ascontiguousarray(colour[:, :, 0]), ""
    if colour.dtype.kind == "f" or colour.dtype == np.uint32:
        raise FormatError(str(path), "channels", "colour float images are not sonar frames")
    return cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), "luma of a colour image"

