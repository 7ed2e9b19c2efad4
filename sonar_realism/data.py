"""Where the real data sets live: one setting for the whole project.

`SONAR_REALISM_DATA` names the data folder; without it, `../shared/data` beside the checkout is used.
`sonar-realism --data DIR COMMAND ...` sets it for one command. No machine's absolute path is ever written
into the repository.
"""

from __future__ import annotations

import os
from pathlib import Path

DATA_ENV = "SONAR_REALISM_DATA"
CHECKOUT = Path(__file__).resolve().parents[1]

# Sub-paths of the two real sets inside the data folder.
REAL_OCULUS = Path("real/oculus_polar_seabed/dataset")
REAL_ARIS = Path("real/marine_debris_watertank/watertank-segmentation")
# Split by recording: fit on the long one, hold the short one out.
OCULUS_FIT_RECORDING = "Oculus_20250805_173650"
OCULUS_HELD_OUT_RECORDING = "Oculus_20250805_171720"


def data_root(override: str | os.PathLike[str] | None = None) -> Path:
    """The data folder: `override` (a `--data` option), else $SONAR_REALISM_DATA, else ../shared/data."""
    if override is not None:
        return Path(override)
    from_env = os.environ.get(DATA_ENV)
    if from_env:
        return Path(from_env)
    return CHECKOUT.parent / "shared" / "data"


def real_oculus_dir(override: str | os.PathLike[str] | None = None) -> Path:
    """The real Oculus polar set (train/ and val/ folders of PNGs, YOLO labels beside them: `yolo_label_file`)."""
    return data_root(override) / REAL_OCULUS


def real_aris_dir(override: str | os.PathLike[str] | None = None) -> Path:
    """The real ARIS water-tank set (Images/, Masks/, BoxAnnotations/)."""
    return data_root(override) / REAL_ARIS


def oculus_recording_files(recording: str, override: str | os.PathLike[str] | None = None) -> list[Path]:
    """Every PNG of one Oculus recording (both folders), in frame order."""
    root = real_oculus_dir(override)
    return sorted(root.glob(f"*/images/{recording}_frame_*.png"), key=lambda path: path.name)


def yolo_label_file(image: str | os.PathLike[str]) -> Path:
    """The YOLO label file of a dataset image: `images/X.png` -> `labels/X.txt` (the Oculus set's layout)."""
    image = Path(image)
    return image.parent.parent / "labels" / f"{image.stem}.txt"
