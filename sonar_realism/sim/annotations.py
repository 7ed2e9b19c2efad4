"""A recording's own object annotations, as objects on each frame's polar grid: where `calibrate --targets-from`
takes the targets' statistics from when a recording has them.

Without annotations `calibrate` counts a target where a long shadow shows; a target that shows as a highlight
with little shadow (the debris on the ARIS tank's floor: objects in every frame by the set's masks, a shadow in a
fifth of them) is missed, and several targets in one frame count as one. Annotations say it directly.

Two forms are read, one file per frame, matched to the frame by its file name's stem (`frame_0001.png` ->
`frame_0001.txt` or `frame_0001.png` under the given folders):

- YOLO box files (`.txt`, `class cx cy w h` per line, normalised to the image the frame was read from);
- class-id mask images (`.png`, 0 = background, each other value a class; every region is one object).

Both are drawn on the image the frame came from: a polar image's rows and columns are the frame's range bins and
beams; a Cartesian fan image (`io/fan.py`) is mapped onto the frame's polar grid through the same layout. A frame
without a file has no objects (the YOLO convention for background frames).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import fan_to_polar
from sonar_realism.io.fan import fan_layout_of
from sonar_realism.io.yolo import read_yolo_labels
from sonar_realism.sim.measure import seabed_rows

SUFFIXES = (".txt", ".png")
# A region smaller than this many polar cells is a labelling speck, not an object.
MIN_OBJECT_CELLS = 4
# Parts of one class this close (polar cells) are one object.
JOIN_CELLS = 2
# Fewer frames than this share with a file means the folders are not this recording's annotations.
MIN_MATCHED_SHARE = 0.5


@dataclass(frozen=True)
class AnnotatedObject:
    """One annotated object on its frame's polar grid: its cells (row and column indices) and class."""

    label: int
    rows: np.ndarray
    cols: np.ndarray


@dataclass(frozen=True)
class Annotations:
    """Every frame's objects (in frame order) and what was read."""

    objects: tuple[tuple[AnnotatedObject, ...], ...]
    files_matched: int
    source: str

    @property
    def frames_with_objects(self) -> int:
        return sum(1 for frame in self.objects if frame)

    @property
    def total(self) -> int:
        return sum(len(frame) for frame in self.objects)


@dataclass(frozen=True)
class ObjectMeasure:
    """What `calibrate` takes from one object: its width across the fan at its range (the size, as the shadow
    measure takes it), its range over the frame's maximum, its return's 95th percentile over the seabed median
    (of the frame scaled to its maximum), and its share of the frame's cells."""

    size_m: float
    range_fraction: float
    highlight: float
    area_share: float


def measure_objects(frame: SonarImage, image: np.ndarray, objects: Sequence[AnnotatedObject]) -> list[ObjectMeasure]:
    """`ObjectMeasure` of each object on `frame` (its metric tables) and `image` (its intensity scaled to [0, 1])."""
    if not objects:
        return []
    seabed = max(float(np.median(image[seabed_rows(image):])), 1e-6)
    beam_step = frame.fov_rad / max(frame.n_beams - 1, 1)
    out = []
    for obj in objects:
        range_m = float(np.median(frame.ranges_m[obj.rows]))
        across = frame.azimuths_rad[obj.cols]
        out.append(ObjectMeasure((float(across.max() - across.min()) + beam_step) * range_m,
                                 range_m / float(frame.ranges_m[-1]),
                                 float(np.percentile(image[obj.rows, obj.cols], 95)) / seabed,
                                 obj.rows.size / image.size))
    return out


def mask_objects(mask: np.ndarray) -> list[AnnotatedObject]:
    """The objects of a simulator's mask (one id per object, 0 = none), for the same measures."""
    return [AnnotatedObject(int(i), *np.nonzero(mask == i)) for i in np.unique(mask) if i != 0]


def parse_classes(text: str) -> frozenset[int]:
    """`"1-10,12"` -> {1, ..., 10, 12}."""
    classes: set[int] = set()
    try:
        for part in filter(None, (p.strip() for p in text.split(","))):
            low, _, high = part.partition("-")
            first, last = int(low), int(high or low)
            if first < 0 or last < first:
                raise ValueError(part)
            classes.update(range(first, last + 1))
    except ValueError as error:
        raise ConfigError(f"--target-classes {text!r}: expected class ids and ranges like 1-10,12") from error
    if not classes:
        raise ConfigError(f"--target-classes {text!r}: no class ids")
    return frozenset(classes)


def annotation_files(folders: Sequence[str | Path]) -> dict[str, Path]:
    """stem -> file over every folder (searched recursively); a stem found twice is an error naming both."""
    found: dict[str, Path] = {}
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise ConfigError(f"--targets-from {folder}: not a folder")
        for path in sorted(folder.rglob("*")):
            if path.suffix.lower() not in SUFFIXES or not path.is_file():
                continue
            if path.stem in found:
                raise ConfigError(f"--targets-from: {found[path.stem]} and {path} annotate the same frame "
                                  f"{path.stem!r}; point at the annotation folders only, not the images beside them")
            found[path.stem] = path
    return found


def read_annotations(frames: Sequence[SonarImage], folders: Sequence[str | Path],
                     classes: frozenset[int] | None = None) -> Annotations:
    """The objects of every frame (as read, before any regridding) from the annotation files under `folders`;
    `classes` keeps only those class ids (a tank wall is annotated, but it is not a target)."""
    files = annotation_files(folders)
    objects, matched = [], 0
    for frame in frames:
        stem = Path(str(frame.meta.get("source", ""))).stem
        path = files.get(stem)
        if path is None:
            objects.append(())
            continue
        matched += 1
        objects.append(tuple(o for o in _frame_objects(path, frame) if classes is None or o.label in classes))
    where = ", ".join(map(str, folders))
    if matched < MIN_MATCHED_SHARE * len(frames):
        example = Path(str(frames[0].meta.get("source", "?"))).stem if frames else "?"
        raise ConfigError(f"--targets-from {where}: only {matched} of {len(frames)} frames have an annotation file "
                          f"(looked for e.g. {example}.txt or {example}.png); point at this recording's labels")
    return Annotations(tuple(objects), matched, f"annotations ({where})")


def _frame_objects(path: Path, frame: SonarImage) -> list[AnnotatedObject]:
    """The objects one annotation file gives its frame, on the frame's polar grid."""
    layout = fan_layout_of(frame)
    height, width = (layout.height_px, layout.width_px) if layout else (frame.n_ranges, frame.n_beams)

    def polar(image: np.ndarray) -> np.ndarray:
        if layout is None:
            return image
        return fan_to_polar(image.astype(np.float32), layout, frame.ranges_m, frame.azimuths_rad,
                            nearest=True).astype(np.int32)

    if path.suffix.lower() == ".txt":
        objects = []
        for box in read_yolo_labels(path):
            drawn = np.zeros((height, width), np.int32)
            top, bottom = int((box.cy - box.height / 2) * height), int(math.ceil((box.cy + box.height / 2) * height))
            left, right = int((box.cx - box.width / 2) * width), int(math.ceil((box.cx + box.width / 2) * width))
            drawn[max(top, 0):bottom, max(left, 0):right] = 1
            rows, cols = np.nonzero(polar(drawn))
            if rows.size >= MIN_OBJECT_CELLS:
                objects.append(AnnotatedObject(box.label, rows, cols))
        return objects
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FormatError(str(path), "mask", "cannot read the image")
    if image.ndim != 2:
        raise FormatError(str(path), "mask", f"a class-id mask has one channel, this one has {image.shape[2]}")
    if image.shape != (height, width):
        raise FormatError(str(path), "mask", f"{image.shape[1]}x{image.shape[0]} px, but its frame's image is "
                                             f"{width}x{height}")
    return _regions(polar(image.astype(np.int32)))


def _regions(classes: np.ndarray) -> list[AnnotatedObject]:
    """One object per region of each class id, parts less than `JOIN_CELLS` apart joined (one object's mask breaks
    into pieces where its surface is shadowed, and a fan mask's thin parts break on the polar grid)."""
    out = []
    join = np.ones((2 * JOIN_CELLS + 1, 2 * JOIN_CELLS + 1), np.uint8)
    for label in np.unique(classes):
        if label == 0:
            continue
        cells = (classes == label).astype(np.uint8)
        count, regions = cv2.connectedComponents(cv2.dilate(cells, join), connectivity=8)
        regions = np.where(cells > 0, regions, 0)
        for region in range(1, count):
            rows, cols = np.nonzero(regions == region)
            if rows.size >= MIN_OBJECT_CELLS:
                out.append(AnnotatedObject(int(label), rows, cols))
    return out
