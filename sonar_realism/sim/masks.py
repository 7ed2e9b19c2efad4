"""Object masks beside the frames `sonar-realism simulate` writes: DIR/masks/NNNNNN.png, one uint8 object id per
[range, beam] pixel (0 = none), numbered in the order the frames are read back from DIR.

The writer (`sim/cli.py`) and every reader (the evaluation's mask IoU, the detection and translator goal scripts)
go through here, so the layout is defined once.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.frames import SonarImage
from sonar_realism.io import read_frames

MASKS_FOLDER = "masks"
# what a simulate manifest says of them
MASK_FILES = f"{MASKS_FOLDER}/NNNNNN.png: uint8 object id per [range, beam] pixel (0 = none)"


def mask_path(folder: str | Path, index: int) -> Path:
    return Path(folder) / MASKS_FOLDER / f"{index:06d}.png"


def clear_masks(folder: str | Path) -> None:
    """Remove the masks an earlier run left in `folder` (a shorter run must not leave the longer one's last masks
    beside its frames)."""
    for path in (Path(folder) / MASKS_FOLDER).glob("[0-9][0-9][0-9][0-9][0-9][0-9].png"):
        path.unlink()


def write_mask(folder: str | Path, index: int, mask: np.ndarray) -> None:
    path = mask_path(folder, index)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.asarray(mask, np.uint8)):
        raise ConfigError(f"could not write {path}")


def read_mask(folder: str | Path, index: int, frame: SonarImage) -> np.ndarray | None:
    """The mask of the `index`-th frame of `folder` (None when the folder has none for it); a mask that is there
    but unreadable or not on the frame's [range, beam] grid is an error, not a silent None."""
    path = mask_path(folder, index)
    if not path.is_file():
        return None
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise FormatError(str(path), "mask", "unreadable PNG")
    if mask.shape != (frame.n_ranges, frame.n_beams):
        raise FormatError(str(path), "mask", f"shape {mask.shape} is not its frame's "
                                             f"{(frame.n_ranges, frame.n_beams)} (ranges, beams)")
    return mask


def frames_with_masks(folder: str | Path) -> Iterator[tuple[SonarImage, np.ndarray | None]]:
    """Each frame of `folder` with its object mask (None where the folder has none)."""
    for index, frame in enumerate(read_frames(folder)):
        yield frame, read_mask(folder, index, frame)
