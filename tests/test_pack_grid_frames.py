"""scripts/pack_grid_frames.py: packed frames load onto the model grid as the originals do, recordings kept."""

from __future__ import annotations

import sys
import zipfile

import numpy as np

from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames
from sonar_realism.models.datasets import load_grid_frames
from tests.repo_script import load_repo_script

pack = load_repo_script("scripts/pack_grid_frames.py", "pack_grid_frames_under_test")


def _frames(recording: str, seed: int, n_ranges: int) -> list[SonarImage]:
    rng = np.random.default_rng(seed)
    return [SonarImage(rng.rayleigh(40, (n_ranges, 48)).clip(0, 255).astype(np.uint8),
                       uniform_ranges(n_ranges, 10.0 + i), uniform_azimuths(48, np.radians(120)), seq=i,
                       meta={"source": f"{recording}_{i:04d}.png"}) for i in range(4)]


def test_packed_frames_load_as_the_originals_and_keep_their_recordings(tmp_path, monkeypatch):
    write_frames([*_frames("Rec_20250805_173650", 0, 70), *_frames("Rec_20250805_171720", 1, 90)],
                 tmp_path / "real")
    out = tmp_path / "packed.npz"
    monkeypatch.setattr(sys, "argv", ["pack_grid_frames.py", "--src", str(tmp_path / "real"), "--grid", "32x16",
                                      "--recordings", "Rec_20250805_173650", "--out", str(out)])
    pack.main()
    original = load_grid_frames(tmp_path / "real", (32, 16))
    packed = load_grid_frames(out, (32, 16))
    kept = np.array([r == "Rec_20250805_173650" for r in original.recordings])
    assert kept.sum() == 4 and set(packed.recordings) == {"Rec_20250805_173650"}
    assert np.abs(packed.images - original.images[kept]).max() < 1e-5
    with zipfile.ZipFile(out) as archive:
        assert all(info.compress_type == zipfile.ZIP_DEFLATED for info in archive.infolist())
