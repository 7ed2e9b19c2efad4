"""A recording's own annotations (YOLO boxes, class-id masks; polar or fan images) as objects on each frame's polar
grid, and `calibrate --targets-from`: the targets' share, count, size and range are recovered from them."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from sonar_realism.cli import main as cli_main
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.geometry import fan_layout, polar_to_fan
from sonar_realism.io import load_recording, read_frames
from sonar_realism.sim.annotations import parse_classes, read_annotations
from sonar_realism.sim.calibrate import CalibrateConfig, calibrate
from sonar_realism.sim.calibrated import simulate_calibrated, target_count
from sonar_realism.sim.calibration import Estimate, load_calibration
from tests.test_sim_calibrate import truth


def polar_folder(tmp_path: Path, n: int = 4, shape: tuple[int, int] = (100, 50)) -> Path:
    folder = tmp_path / "images"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(folder / f"f_{i:02d}.png"), rng.integers(10, 60, shape, dtype=np.uint8))
    return folder


def test_yolo_boxes_on_polar_frames_land_on_their_range_bins_and_beams(tmp_path: Path) -> None:
    frames = list(read_frames(polar_folder(tmp_path)))
    labels = tmp_path / "labels"
    labels.mkdir()
    (labels / "f_00.txt").write_text("2 0.5 0.25 0.2 0.1\n\n0 0.1 0.9 0.1 0.1\n")
    (labels / "f_01.txt").write_text("")  # a background frame
    (labels / "f_02.txt").write_text("5 0.5 0.5 0.5 0.5\n")
    annotations = read_annotations(frames, [labels])
    assert annotations.files_matched == 3 and annotations.total == 3 and annotations.frames_with_objects == 2
    first = annotations.objects[0][0] if annotations.objects[0][0].label == 2 else annotations.objects[0][1]
    assert (first.rows.min(), first.rows.max() + 1) == (20, 30)  # rows = range bins: 0.25 ± 0.05 of 100
    assert (first.cols.min(), first.cols.max() + 1) == (20, 30)  # columns = beams: 0.5 ± 0.1 of 50
    assert annotations.objects[3] == ()  # no file: no objects
    only = read_annotations(frames, [labels], parse_classes("1-3"))
    assert only.total == 1 and only.objects[0][0].label == 2


def test_class_masks_on_fan_images_map_onto_the_polar_frame_one_object_per_region(tmp_path: Path) -> None:
    polar = SonarImage(np.full((120, 40), 90, np.uint8), uniform_ranges(120, 6.0, 1.0),
                       uniform_azimuths(40, math.radians(30.0)))
    images, masks = tmp_path / "Images", tmp_path / "Masks"
    images.mkdir()
    masks.mkdir()
    layout = fan_layout(polar, 320)
    (images / "sonar.json").write_text(json.dumps({"kind": "fan", "px_per_m": layout.px_per_m}))
    for i in range(2):
        cv2.imwrite(str(images / f"tank-{i}.png"), polar_to_fan(polar, 320))
        # class 3 at 3 m straight ahead and at 5 m to one side, class 11 (a wall) across the far edge
        mask = np.zeros((layout.height_px, layout.width_px), np.uint8)
        for range_m, bearing, label in ((3.0, 0.0, 3), (5.0, math.radians(8.0), 3)):
            x = layout.apex_x_px + range_m * math.sin(bearing) * layout.px_per_m
            y = layout.apex_y_px - range_m * math.cos(bearing) * layout.px_per_m
            cv2.circle(mask, (round(x), round(y)), round(0.2 * layout.px_per_m), label, -1)
        mask[: round(layout.apex_y_px - 5.8 * layout.px_per_m)] = 11
        cv2.imwrite(str(masks / f"tank-{i}.png"), mask)
    frames = list(read_frames(images))
    assert frames[0].meta["converted_from"] == "fan"
    annotations = read_annotations(frames, [masks], parse_classes("1-10"))
    assert [len(objects) for objects in annotations.objects] == [2, 2]
    frame = frames[0]
    found = sorted((float(np.median(frame.ranges_m[o.rows])), float(np.median(frame.azimuths_rad[o.cols])))
                   for o in annotations.objects[0])
    assert found[0] == pytest.approx((3.0, 0.0), abs=0.05)
    assert found[1][0] == pytest.approx(5.0, abs=0.05) and math.degrees(found[1][1]) == pytest.approx(8.0, abs=1.0)
    assert read_annotations(frames, [masks]).total == 6  # the wall counts when every class does
    cv2.imwrite(str(masks / "tank-1.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(FormatError, match="tank-1.png.*mask.*10x10"):
        read_annotations(frames, [masks])


def test_bad_annotations_name_the_file_the_line_or_what_is_missing(tmp_path: Path) -> None:
    frames = list(read_frames(polar_folder(tmp_path)))
    labels = tmp_path / "labels"
    labels.mkdir()
    (labels / "f_00.txt").write_text("1 0.5 0.5 0.1\n")
    (labels / "f_01.txt").write_text("1 0.5 0.5 0.1 0.1\n")
    (labels / "f_02.txt").write_text("1 0.5 0.5 0.1 0.1\n")
    with pytest.raises(FormatError, match="f_00.txt.*line 1"):
        read_annotations(frames, [labels])
    (labels / "f_00.txt").unlink()
    (labels / "f_02.txt").unlink()
    with pytest.raises(ConfigError, match="only 1 of 4 frames"):
        read_annotations(frames, [labels])
    with pytest.raises(ConfigError, match="same frame"):  # pointed at the images themselves as well
        read_annotations(frames, [labels, tmp_path / "images"])
    with pytest.raises(ConfigError, match="not a folder"):
        read_annotations(frames, [tmp_path / "nowhere"])
    with pytest.raises(ConfigError, match="1-10,12"):
        parse_classes("walls")


def test_target_count_keeps_one_target_without_a_draw_and_averages_the_calibrated_count() -> None:
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    assert target_count(1.0, rng) == 1 and rng.bit_generator.state == state
    assert np.mean([target_count(2.5, rng) for _ in range(4000)]) == pytest.approx(2.5, abs=0.08)


KNOWN = dataclasses.replace(truth(), targets=dataclasses.replace(
    truth().targets, present_fraction=Estimate(1.0, 1.0, 1.0), count=Estimate(2.0, 2.0, 2.0)))


@pytest.fixture(scope="module")
def annotated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[int]]:
    """A recording of a known calibration (two targets a frame on average) as PNGs, its masks beside."""
    root = tmp_path_factory.mktemp("annotated")
    images, masks = root / "images", root / "masks"
    images.mkdir()
    masks.mkdir()
    counts = []
    for i, (frame, mask) in enumerate(simulate_calibrated(KNOWN, 12, seed=3)):
        cv2.imwrite(str(images / f"rec_{i:03d}.png"), frame.intensity)
        cv2.imwrite(str(masks / f"rec_{i:03d}.png"), mask)  # object ids stand in for classes
        counts.append(len(set(np.unique(mask)) - {0}))
    return images, masks, counts


def test_calibrate_takes_the_targets_of_a_known_recording_from_its_masks(annotated) -> None:
    images, masks, counts = annotated
    frames = load_recording(images)
    config = CalibrateConfig(sim_frames=2, mounting_frames=4, rounds=1, bootstrap=20, effect_bootstrap=0,
                             texture="none", default_fov_deg=90.0, default_range_bin_m=0.05)
    targets = calibrate(frames, "known", config, annotations=read_annotations(frames, [masks])).calibration.targets
    assert targets.present_fraction.value == 1.0
    assert targets.count.value == pytest.approx(np.mean(counts), abs=0.2) and targets.count.value > 1.2
    assert 0.4 <= targets.size_m.value <= 1.3  # 0.8 m targets (log-normal spread), the lit surface's width
    assert targets.range_fraction.value == pytest.approx(0.5, abs=0.15)
    assert targets.source.startswith("annotations") and f"in {len(frames)} of {len(frames)} frames" in targets.source
    # and the simulator then draws that many targets a frame
    masks_out = [m for _, m in simulate_calibrated(dataclasses.replace(KNOWN, targets=targets), 12, seed=9)]
    assert np.mean([len(set(np.unique(m)) - {0}) for m in masks_out]) > 1.2


def test_calibrate_cli_reads_annotations_and_says_so(annotated, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    images, masks, _ = annotated
    out = tmp_path / "CALIB.json"
    fast = ["--sim-frames", "2", "--rounds", "1", "--effect-bootstrap", "0", "--texture", "none"]
    assert cli_main(["calibrate", "--real", str(images), "--out", str(out), "--targets-from", str(masks),
                     "--target-classes", "1", *fast]) == 0
    targets = load_calibration(out).targets
    assert targets.count.value == 1.0 and targets.source.startswith("annotations")  # object 1 only
    assert "targets in such a frame" in out.with_suffix(".html").read_text()
    assert cli_main(["calibrate", "--real", str(images), "--out", str(tmp_path / "c.json"), "--target-classes",
                     "1", *fast]) == 2
    assert "--target-classes needs --targets-from" in capsys.readouterr().err
    assert not (tmp_path / "c.json").exists()
