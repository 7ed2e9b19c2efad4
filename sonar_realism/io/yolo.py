"""YOLO label files: one object per line, `class cx cy w h`, the box normalised to its image (the Oculus set's
`labels/X.txt` beside `images/X.png`). Read by the detection goal and by `calibrate --targets-from`."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from sonar_realism.errors import FormatError


class YoloLabel(NamedTuple):
    label: int
    cx: float
    cy: float
    width: float
    height: float


def read_yolo_labels(path: str | Path) -> list[YoloLabel]:
    """Every line of a YOLO label file; blank lines are skipped, anything else malformed is a FormatError naming
    the file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise FormatError(str(path), "labels", f"cannot read the label file ({error})") from error
    labels = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) != 5:
            raise FormatError(str(path), f"line {number}", f"expected 'class cx cy w h', got {line.strip()!r}")
        try:
            label, cx, cy, width, height = int(fields[0]), *(float(f) for f in fields[1:])
        except ValueError as error:
            raise FormatError(str(path), f"line {number}", f"not numbers: {line.strip()!r}") from error
        if label < 0 or not all(0.0 <= v <= 1.0 for v in (cx, cy, width, height)) or width <= 0 or height <= 0:
            raise FormatError(str(path), f"line {number}", "class must be >= 0 and cx cy w h in [0, 1] with w, h > 0, "
                                                           f"got {line.strip()!r}")
        labels.append(YoloLabel(label, cx, cy, width, height))
    return labels
