"""Training data for the cDFCVAE: recordings -> float32 images on the model grid, split by recording.

Frames are read with `sonar_realism.io.read_frames` (any supported recording), resampled onto the model's
uniform (n_ranges, n_beams) grid over the same span with `sonar_realism.geometry.resample_to_grid`, and
normalised to [0, 1]. The real Oculus set was exported with a per-frame rescale by the frame maximum
(its README), so "frame_max" normalisation applies the same rule to every frame (real and simulated) and
the model never sees an absolute gain that only one domain has.

Validation frames must come from recordings the model did not train on: consecutive pings of one recording
are nearly identical, so a random split would leak and early stopping would never trigger.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import resample_like, resample_to_grid
from sonar_realism.io import read_frames, sniff

Normalisation = Literal["frame_max", "full_scale"]
# Trailing frame counters in file names ("Oculus_20250805_171720_frame_00020.png", "sim_000012.png").
_FRAME_COUNTER = re.compile(r"([_-]?(frame|ping|img|image))?[_-]?\d+$", re.IGNORECASE)


@dataclass(frozen=True)
class GridFrames:
    """Images on the model grid with the recording each one came from."""

    images: np.ndarray  # [N, n_ranges, n_beams] float32 in [0, 1]
    recordings: tuple[str, ...]

    def subset(self, indices: np.ndarray) -> GridFrames:
        return GridFrames(self.images[indices], tuple(self.recordings[i] for i in indices))

    def __len__(self) -> int:
        return int(self.images.shape[0])


def recording_of(frame: SonarImage, fallback: str) -> str:
    """The recording a frame belongs to: its source file name without the frame counter, else `fallback`."""
    source = frame.meta.get("recording") or frame.meta.get("source")
    if not isinstance(source, str) or not source:
        return fallback
    stem = Path(source).stem
    return _FRAME_COUNTER.sub("", stem) or stem


def normalise(frame: SonarImage, how: Normalisation) -> np.ndarray:
    """float32 [..., R, B] in [0, 1]: by full scale, or by each sample's maximum (the real set's export rule)."""
    image = frame.normalized()
    if how == "frame_max":
        peak = image.max(axis=(-2, -1), keepdims=True)
        image = image / np.maximum(peak, np.float32(1e-6))
    return image.astype(np.float32, copy=False)


def to_model_grid(frame: SonarImage, grid: tuple[int, int], how: Normalisation) -> np.ndarray:
    """A frame (2-D or with samples) as normalised float32 on the model grid, [..., grid[0], grid[1]]."""
    if (frame.n_ranges, frame.n_beams) != tuple(grid):
        frame = resample_to_grid(frame, grid[0], grid[1])
    return normalise(frame, how)


def frames_on_grid(frames: Sequence[SonarImage], grid: tuple[int, int]) -> np.ndarray:
    """Frames on the model grid, max-scaled, one image per sample: [images, grid rows, grid cols] (what the
    whole-frame tests and the realism CNN take)."""
    return np.concatenate([to_model_grid(f, grid, "frame_max").reshape(-1, *grid) for f in frames])


def from_model_grid(frame: SonarImage, images: np.ndarray) -> np.ndarray:
    """The inverse of `to_model_grid`: float32 images [..., grid rows, grid cols] on `frame`'s own ranges and
    bearings, [..., frame.n_ranges, frame.n_beams]."""
    grid = tuple(images.shape[-2:])
    if (frame.n_ranges, frame.n_beams) == grid:
        return images.astype(np.float32, copy=False)
    on_grid = resample_to_grid(frame, *grid).replace(intensity=images.astype(np.float32, copy=False),
                                                     intensity_scale=1.0)
    return resample_like(on_grid, frame).intensity.astype(np.float32, copy=False)


def recording_sources(path: Path) -> list[Path]:
    """What to hand read_frames: `path` itself, plus (for a plain folder) its sub-folders, recursively,
    so a dataset laid out as train/images + val/images is read whole and split by recording here."""
    if not path.is_dir() or sniff(path) == "frames-folder":
        return [path]
    children = sorted(child for child in path.iterdir() if child.is_dir())
    has_files = any(child.is_file() for child in path.iterdir())
    return ([path] if has_files or not children else []) + [s for c in children for s in recording_sources(c)]


def _images_of(path: str | Path, image_of: Callable[[SonarImage], np.ndarray], max_frames: int | None
               ) -> tuple[list[np.ndarray], list[str]]:
    """`image_of` of every frame of the recording(s) at `path`, one image per sample, with the recording of each;
    at most `max_frames` images."""
    images: list[np.ndarray] = []
    recordings: list[str] = []
    for source in recording_sources(Path(path)):
        for frame in read_frames(source):
            level = image_of(frame)
            samples = level.reshape(-1, *level.shape[-2:])
            images.extend(samples)
            recordings.extend([recording_of(frame, source.name)] * len(samples))
            if max_frames is not None and len(images) >= max_frames:
                return images[:max_frames], recordings[:max_frames]
    if not images:
        raise ConfigError(f"{path}: no frames found")
    return images, recordings


def load_grid_frames(path: str | Path, grid: tuple[int, int], how: Normalisation = "frame_max",
                     max_frames: int | None = None) -> GridFrames:
    """Every frame of the recording(s) at `path` on the model grid (multi-sample frames give one image each)."""
    images, recordings = _images_of(path, lambda frame: to_model_grid(frame, grid, how), max_frames)
    return GridFrames(np.stack(images).astype(np.float32), tuple(recordings))


def load_native_frames(path: str | Path, how: Normalisation = "frame_max",
                       max_frames: int | None = None) -> list[np.ndarray]:
    """Every frame of the recording(s) at `path` at its own resolution, normalised (multi-sample frames give one
    image each): what a fully convolutional model trains on in crops."""
    return _images_of(path, lambda frame: normalise(frame, how), max_frames)[0]


def random_crops(images: Sequence[np.ndarray], count: int, crop: int, rng: np.random.Generator) -> np.ndarray:
    """`count` crops of crop × crop cells, each from a frame and a place drawn uniformly, [count, crop, crop]."""
    picks = rng.integers(0, len(images), count)
    out = np.empty((count, crop, crop), np.float32)
    for i, pick in enumerate(picks):
        image = images[pick]
        row = rng.integers(0, image.shape[0] - crop + 1)
        col = rng.integers(0, image.shape[1] - crop + 1)
        out[i] = image[row:row + crop, col:col + crop]
    return out


def split_by_recording(frames: GridFrames, val_recordings: Sequence[str] = (), val_fraction: float = 0.2,
                       ) -> tuple[np.ndarray, np.ndarray, str]:
    """(train indices, validation indices, how it was split).

    Named `val_recordings` go to validation; otherwise the smallest recording is held out. With a single
    recording its last `val_fraction` (in time) is held out instead: the nearest thing to an unseen one."""
    recordings = np.asarray(frames.recordings)
    names, counts = np.unique(recordings, return_counts=True)
    if val_recordings:
        unknown = sorted(set(val_recordings) - set(names))
        if unknown:
            raise ConfigError(f"validation recordings {unknown} not in the data (have {', '.join(names)})")
        held = sorted(val_recordings)
    elif len(names) > 1:
        held = [str(names[int(np.argmin(counts))])]
    else:
        n_val = max(1, int(round(val_fraction * len(frames)))) if len(frames) > 1 else 0
        order = np.arange(len(frames))
        return order[: len(frames) - n_val], order[len(frames) - n_val:], "single recording: last frames in time"
    is_val = np.isin(recordings, held)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val), f"by recording: validation = {', '.join(held)}"


def batches(images: np.ndarray, batch_size: int, rng: np.random.Generator | None,
            flip_beams: bool = False) -> Iterator[torch.Tensor]:
    """[B, 1, R, B] float tensors; shuffled and randomly mirrored left-right when `rng` is given
    (a port/starboard mirror is a physically valid sonar frame; a range flip is not)."""
    order = rng.permutation(len(images)) if rng is not None else np.arange(len(images))
    for start in range(0, len(order), batch_size):
        chunk = images[order[start:start + batch_size]]
        if rng is not None and flip_beams:
            mirror = rng.random(len(chunk)) < 0.5
            chunk = np.where(mirror[:, None, None], chunk[:, :, ::-1], chunk)
        yield torch.from_numpy(np.ascontiguousarray(chunk, dtype=np.float32)).unsqueeze(1)
