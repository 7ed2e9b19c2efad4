"""Pack recordings onto a model grid in one small, deflated NPZ, for training on a machine that cannot see them.

A lent GPU machine receives only this repository (64 MiB in all), not `../shared`: the real fit recording's PNGs (53
MB) and 400 simulated frames (28 MB) do not fit beside it. Training reads every frame through `load_grid_frames`,
i.e. resampled onto the model grid and divided by its own maximum, so this stores exactly that (as uint16 of the
normalised level: an error under 1e-5 of full scale) with each frame's source kept, so the split by recording is
unchanged. One file holds one geometry: every frame carries the first one's grid ranges and bearings (on the model
grid training uses the levels alone). Training on the packed file then sees the same arrays as training on the
originals. The learned texture, fitted at the frames' own resolution, is not served by it: refit it where the
originals are (scripts/refit_texture.py).

    python scripts/pack_grid_frames.py --src ../shared/data/real/oculus_polar_seabed/dataset \\
        --recordings Oculus_20250805_173650 --grid 128x128 --out runs/gpu/real_fit.npz
"""

from __future__ import annotations

import argparse
import os
import zipfile
from pathlib import Path

import numpy as np

from sonar_realism.config import parse_grid
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import resample_to_grid
from sonar_realism.io import read_frames
from sonar_realism.io.npz import write_npz
from sonar_realism.models.datasets import recording_of, recording_sources, to_model_grid

FULL_SCALE = 65535


def grid_frames(src: Path, grid: tuple[int, int], recordings: set[str] | None) -> list[SonarImage]:
    packed = []
    for source in recording_sources(src):
        for frame in read_frames(source):
            if recordings is not None and recording_of(frame, source.name) not in recordings:
                continue
            level = to_model_grid(frame, grid, "frame_max")
            if not packed:
                geometry = resample_to_grid(frame, *grid) if (frame.n_ranges, frame.n_beams) != grid else frame
            quantised = np.round(level * FULL_SCALE).astype(np.uint16)
            packed.append(SonarImage(quantised, geometry.ranges_m, geometry.azimuths_rad, stamp_ns=frame.stamp_ns,
                                     seq=frame.seq, intensity_scale=float(FULL_SCALE),
                                     meta={"recording": _recording_field(frame, source)}))
    return packed


def _recording_field(frame: SonarImage, source: Path) -> str:
    """What `recording_of` reads, as the original frame gives it, so the packed frame names the same recording."""
    return frame.meta.get("recording") or frame.meta.get("source") or source.name


def deflate(path: Path) -> None:
    """write_npz stores its members uncompressed (it streams); the reader takes deflated members just as well."""
    partial = path.with_name(path.name + ".deflated")
    with zipfile.ZipFile(path) as stored, zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as packed:
        for member in stored.namelist():
            packed.writestr(member, stored.read(member))
    os.replace(partial, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", required=True, help="recording(s), anything load_grid_frames reads")
    parser.add_argument("--grid", default="128x128", help="the model grid RANGESxBEAMS (default 128x128)")
    parser.add_argument("--recordings", help="comma-separated recordings to keep (default: all)")
    parser.add_argument("--out", required=True, help="the .npz to write")
    args = parser.parse_args()
    keep = set(args.recordings.split(",")) if args.recordings else None
    frames = grid_frames(Path(args.src), parse_grid(args.grid), keep)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_npz(frames, out)
    deflate(out)
    print(f"{out}: {len(frames)} frames, {out.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
