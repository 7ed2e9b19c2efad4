"""`sonar-realism simulate`: frames folder, masks and manifest on disk; clear errors; the committed sample."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from sonar_realism.cli import main
from sonar_realism.errors import FormatError
from sonar_realism.io import read_frames
from sonar_realism.sim import simulate
from sonar_realism.sim.effects import PIPELINE_ORDER
from sonar_realism.sim.masks import frames_with_masks
from sonar_realism.sim.sensor import SENSORS

SMALL_GRID = ["--beams", "48", "--ranges", "96", "--range-m", "10", "--quiet"]
SAMPLE = Path(__file__).resolve().parents[1] / "sonar_realism" / "assets" / "sim_sample"


def test_raw_sim_folder_reads_back_with_masks_and_manifest(tmp_path: Path) -> None:
    out = tmp_path / "raw"
    assert main(["simulate", "--n", "3", "--out", str(out), "--seed", "4", *SMALL_GRID]) == 0
    frames = list(read_frames(out))
    assert len(frames) == 3
    assert all(f.intensity.shape == (96, 48) and f.intensity.dtype == np.float32 for f in frames)
    assert frames[0].meta["scene"] == "default" and frames[0].max_range_m < 10.0
    masks = sorted((out / "masks").glob("*.png"))
    assert len(masks) == 3
    read_back = [mask for _, mask in frames_with_masks(out)]
    assert all(m.shape == (96, 48) and m.dtype == np.uint8 for m in read_back)
    sensor = dataclasses.replace(SENSORS["m1200d_1200khz"], n_ranges=96, n_beams=48, max_range_m=10.0)
    for mask, (_, simulated) in zip(read_back, simulate(scene="default", n=3, seed=4, sensor=sensor), strict=True):
        np.testing.assert_array_equal(mask, simulated)  # frame i's mask, in the order the frames read back
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["scene"] == "default" and manifest["seed"] == 4 and manifest["n"] == 3
    assert manifest["effects"] == [] and len(manifest["poses"]) == 3 and manifest["objects"]
    assert manifest["sensor"]["n_beams"] == 48 and "simulate" in manifest["command"]
    # the written frames are the simulator's frames, bit for bit
    again = tmp_path / "again"
    assert main(["simulate", "--n", "3", "--out", str(again), "--seed", "4", *SMALL_GRID]) == 0
    for a, b in zip(frames, read_frames(again), strict=True):
        np.testing.assert_array_equal(a.intensity, b.intensity)


def test_a_shorter_run_into_the_same_folder_leaves_no_masks_of_the_longer_one(tmp_path: Path) -> None:
    out = tmp_path / "raw"
    assert main(["simulate", "--n", "4", "--out", str(out), *SMALL_GRID]) == 0
    assert main(["simulate", "--n", "2", "--out", str(out), "--seed", "1", *SMALL_GRID]) == 0
    assert sorted(p.name for p in (out / "masks").glob("*.png")) == ["000000.png", "000001.png"]

def test_masks_are_none_where_a_folder_has_none_and_an_error_where_one_does_not_fit(tmp_path: Path) -> None:
    out = tmp_path / "raw"
    assert main(["simulate", "--n", "2", "--out", str(out), *SMALL_GRID]) == 0
    (out / "masks" / "000001.png").unlink()
    assert [mask is None for _, mask in frames_with_masks(out)] == [False, True]
    cv2.imwrite(str(out / "masks" / "000001.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(FormatError, match=r"000001\.png: mask: shape \(10, 10\)"):
        list(frames_with_masks(out))


def test_all_effects_with_overrides_recorded(tmp_path: Path) -> None:
    out = tmp_path / "all"
    assert main(["simulate", "--scene", "organic", "--effects", "all", "--n", "2", "--out", str(out),
                 "--param", "speckle.shape_nu=2.5", "--param", "multipath.n_ghosts=2", *SMALL_GRID]) == 0
    frames = list(read_frames(out))
    assert all(f.intensity.dtype == np.uint8 for f in frames)
    manifest = json.loads((out / "manifest.json").read_text())
    assert [e["name"] for e in manifest["effects"]] == list(PIPELINE_ORDER)
    params = {e["name"]: e["params"] for e in manifest["effects"]}
    assert params["speckle"]["shape_nu"] == 2.5 and params["multipath"]["n_ghosts"] == 2
    assert manifest["storage"] == "uint8"


def test_uint16_storage_is_compact_and_faithful(tmp_path: Path) -> None:
    out = tmp_path / "u16"
    assert main(["simulate", "--n", "1", "--out", str(out), "--dtype", "uint16", *SMALL_GRID]) == 0
    frame = next(iter(read_frames(out)))
    assert frame.intensity.dtype == np.uint16 and frame.intensity_scale == 65535.0
    reference = tmp_path / "f32"
    assert main(["simulate", "--n", "1", "--out", str(reference), *SMALL_GRID]) == 0
    exact = next(iter(read_frames(reference)))
    np.testing.assert_allclose(frame.normalized(), exact.normalized(), atol=1 / 65535)


@pytest.mark.parametrize(("extra", "message"), [
    (["--effects", "speckle,sparkle"], "known effects: .*tvg_noise"),
    (["--param", "speckle.shape_nu"], "EFFECT.NAME=VALUE"),
    (["--param", "speckle.shape_nu=soft"], "not a number"),
    (["--effects", "speckle", "--param", "speckle.shape_nu=-3"], "speckle.shape_nu"),
    (["--range-m", "0.1"], "max_range_m"),
    (["--scene", "moon"], "known scenes"),
    (["--n", "0"], "--n"),
])
def test_bad_requests_fail_with_a_clear_message(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                extra: list[str], message: str) -> None:
    args = ["simulate", "--n", "1", "--out", str(tmp_path / "bad"), "--quiet", *extra]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "error" in err and re.search(message, err), err
    assert not (tmp_path / "bad" / "frames.jsonl").exists()


@pytest.mark.skipif(not (SAMPLE / "frames.jsonl").exists(), reason="committed sample not present")
def test_committed_sample_is_readable_offline() -> None:
    manifest = json.loads((SAMPLE / "manifest.json").read_text())
    frames = list(read_frames(SAMPLE))
    assert len(frames) == manifest["n"] >= 12
    assert manifest["scene"] == "default" and manifest["effects"] == []
    assert len(list((SAMPLE / "masks").glob("*.png"))) == len(frames)
    assert frames[0].n_beams == 256 and frames[0].meta["source"] == "sim"
    assert sum(p.stat().st_size for p in SAMPLE.rglob("*") if p.is_file()) < 5_000_000
