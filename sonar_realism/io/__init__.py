"""Reading and writing sonar recordings: one entry point that picks the reader from the content.

`read_frames(path)` reads a single file or a folder: frames folders written by `write_frames`, Oculus
`.oculus` logs and raw message streams (`sonar_realism.io.oculus`), NPZ files, PNG/TIFF polar images
and Cartesian fan images with optional JSON sidecars, ROS 1 bags, ROS 2 bag folders and MCAP files
(`sonar_realism.io.rosbag`). The reader is chosen by magic bytes, never by the
extension alone. Everything streams: a frame is decoded when the iterator reaches it.

Formats are described in docs/formats.md.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from sonar_realism.errors import FormatError
from sonar_realism.frames import SonarImage
from sonar_realism.io import folder, npz, oculus, rosbag
from sonar_realism.io.report import ReadReport

__all__ = ["FILE_SUFFIXES", "ReadReport", "load_recording", "read_frames", "write_frames", "sniff"]

# write_frames writes a file for these suffixes (an NPZ, a ROS 2 MCAP bag), a frames folder for any other path
_FILE_WRITERS = {".npz": npz.write_npz, ".mcap": rosbag.write_mcap}
FILE_SUFFIXES = tuple(_FILE_WRITERS)

_HEAD_BYTES = 64


def sniff(path: str | Path) -> str | None:
    """What `path` holds: "frames-folder", "folder", "ros2_bag", "ros1_bag", "mcap", "png", "tiff", "npz",
    "oculus_log", "oculus_raw", or None."""
    path = Path(path)
    if path.is_dir():
        if folder.is_frames_folder(path):
            return "frames-folder"
        return rosbag.sniff(path, b"") or "folder"
    if path.name == folder.INDEX_NAME:
        return "frames-folder"
    with open(path, "rb") as stream:
        head = stream.read(_HEAD_BYTES)
    if head.startswith(folder.PNG_MAGIC):
        return "png"
    if head.startswith(folder.TIFF_MAGICS):
        return "tiff"
    if head.startswith(npz.ZIP_MAGIC):
        return "npz"
    # A raw Oculus capture need not start on a message boundary: look for a ping header further in.
    return (rosbag.sniff(path, head) or oculus.sniff(head)
            or ("oculus_raw" if oculus.starts_mid_capture(path) else None))


def read_frames(path: str | Path, report: ReadReport | None = None, topic: str | None = None,
                geometry: dict[str, Any] | None = None) -> Iterator[SonarImage]:
    """Every frame of the recording at `path` (a file or a folder), in recording order.

    Files a reader does not own are counted in `report.skipped`; corrupt records it can step over are in
    `report.problems`; input it cannot make sense of raises FormatError naming the file and field.
    For ROS bags, `topic` chooses the sonar topic (default: the one sonar topic found by type) and
    `geometry` (sidecar keys, docs/formats.md) gives sensor_msgs/Image frames their geometry.
    """
    path = Path(path)
    report = report if report is not None else ReadReport()
    report.source = report.source or str(path)
    if not path.exists():
        raise FormatError(str(path), "path", "no such file or folder")
    kind = sniff(path)
    if kind == "frames-folder":
        yield from folder.read_frames_folder(path if path.is_dir() else path.parent, report)
    elif kind == "folder":
        yield from _read_plain_folder(path, report)
    elif kind in rosbag.KINDS:
        yield from rosbag.read_bag(path, kind, report, topic, geometry)
    else:
        yield from _read_file(path, kind, report)


def load_recording(path: str | Path, match: str | None = None, limit: int | None = None) -> list[SonarImage]:
    """Every frame of `path` as `read_frames` reads it; a folder with no frames of its own but subfolders (a data
    set split into train/images, val/images) is read folder by folder, its frames in source-name order. `match`
    keeps the frames whose source name contains it; `limit` thins them evenly to at most that many."""
    path = Path(path)
    frames = list(read_frames(path))
    if not frames and path.is_dir():
        # a frames folder's own frames/ and geometry/ are read with it, not again as folders of images
        folders = sorted(p for p in path.rglob("*") if p.is_dir()
                         and not any(folder.is_frames_folder(up) for up in p.parents if path in up.parents))
        frames = sorted((f for sub in folders for f in read_frames(sub)),
                        key=lambda f: str(f.meta.get("source", "")))
    frames = [f for f in frames if match is None or match in str(f.meta.get("source", ""))]
    if limit and len(frames) > limit:
        frames = frames[:: max(1, len(frames) // limit)][:limit]
    return frames


def write_frames(frames: Iterable[SonarImage], path: str | Path) -> int:
    """Write `frames` to `path`: an NPZ file when the name ends in .npz, a ROS 2 MCAP bag when it ends in .mcap,
    else a frames folder. Returns the count.

    All are streamed (one frame in memory at a time) and read back losslessly by `read_frames`.
    """
    path = Path(path)
    writer = _FILE_WRITERS.get(path.suffix.lower())
    return writer(frames, path) if writer is not None else folder.write_frames_folder(frames, path)


def _read_plain_folder(path: Path, report: ReadReport) -> Iterator[SonarImage]:
    """Each recognised file of the folder in natural name order; sidecars are read with their images."""
    position = 0
    for child in sorted(path.iterdir(), key=folder.natural_key):
        if child.is_dir():
            report.skip("subfolder")
            continue
        if child.suffix.lower() == ".json" or child.name.endswith(".tmp"):
            continue  # sidecars (read with their image) and files still being written
        kind = sniff(child)
        if kind is None:
            report.skip(f"not a frame file ({child.suffix or child.name})")
            continue
        for frame in _read_file(child, kind, report, position):
            position += 1
            yield frame


def _read_file(path: Path, kind: str | None, report: ReadReport, position: int = 0) -> Iterator[SonarImage]:
    if kind in ("png", "tiff"):
        yield from folder.read_image_file(path, report, position)
    elif kind == "npz":
        yield from npz.read_npz(path, report)
    elif kind in ("oculus_log", "oculus_raw"):
        yield from oculus.read_oculus(path, report)
    elif kind in rosbag.KINDS:
        yield from rosbag.read_bag(path, kind, report)
    else:
        raise FormatError(str(path), "magic",
                          "unrecognised content (not a frames folder, PNG, TIFF, NPZ, Oculus, ROS bag or MCAP)")

