"""The downstream detection measure: AP, boxes from sim masks and YOLO labels, and a detector that learns."""

from pathlib import Path

import numpy as np
import pytest

from sonar_realism.data import OCULUS_HELD_OUT_RECORDING, oculus_recording_files, yolo_label_file
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.evaluate.detection import (
    Box,
    Detection,
    DetectorConfig,
    augment,
    average_precision,
    detect,
    detector_image,
    mask_boxes,
    read_yolo_boxes,
    train_detector,
)
from sonar_realism.frames import SonarImage, uniform_ranges


def test_ap_is_one_for_perfect_predictions_and_zero_for_none() -> None:
    truth = [[Box(10, 10, 20, 30)], [Box(50, 60, 70, 64), Box(0, 0, 8, 8)]]
    perfect = [[Detection(box, 0.9) for box in frame] for frame in truth]
    assert average_precision(perfect, truth) == pytest.approx(1.0)
    assert average_precision([[], []], truth) == 0.0


def test_ap_hand_worked_case() -> None:
    truth = [[Box(0, 0, 10, 10)], [Box(0, 0, 10, 10)]]
    predictions = [
        [Detection(Box(0, 0, 10, 10), 0.9),  # TP
         Detection(Box(0, 0, 10, 11), 0.8)],  # a duplicate of a claimed box: FP
        [Detection(Box(1, 1, 11, 11), 0.7),  # IoU 81/119 = 0.68: TP
         Detection(Box(40, 40, 50, 50), 0.95)],  # FP, ranked first
    ]
    # ranked FP, TP, FP, TP: precision 0, 1/2, 1/3, 2/4 at recall 0, 1/2, 1/2, 1; its monotone envelope is
    # 1/2 up to recall 1 -> AP = 0.5 * 0.5 + 0.5 * 0.5
    assert average_precision(predictions, truth) == pytest.approx(0.5)
    # The stray box ranked third instead (TP, FP, FP, TP): precision 1 up to recall 1/2, then 2/4 -> 0.5 + 0.25
    predictions[1][1] = Detection(Box(40, 40, 50, 50), 0.75)
    assert average_precision(predictions, truth) == pytest.approx(0.75)
    # A stricter IoU turns the 0.68 match into a miss.
    assert average_precision(predictions, truth, iou=0.75) == pytest.approx(0.5)


def test_ap_rejects_mismatched_or_empty_ground_truth() -> None:
    with pytest.raises(ConfigError, match="prediction lists"):
        average_precision([[]], [[], []])
    with pytest.raises(ConfigError, match="no ground-truth"):
        average_precision([[]], [[]])


def _frame(n_ranges: int, azimuths: np.ndarray) -> SonarImage:
    return SonarImage(intensity=np.zeros((n_ranges, azimuths.shape[0]), np.float32),
                      ranges_m=uniform_ranges(n_ranges, 10.0), azimuths_rad=azimuths)


def test_mask_boxes_one_box_per_object_id_on_the_grid() -> None:
    frame = _frame(64, np.linspace(-0.5, 0.5, 32))
    mask = np.zeros((64, 32), np.uint8)
    mask[10:20, 4:8] = 1
    mask[40:42, 20:30] = 3
    mask[45, 25] = 3  # the same object, a separate component: still one box
    boxes = mask_boxes(mask, frame, (128, 128))
    assert len(boxes) == 2
    first, second = boxes
    # Grid cell centres run from the first bin's centre to the last's: bin edge e (in bins) lies at grid
    # coordinate e * (128 - 1) / (bins - 1) + 0.5.
    def on_grid(edge: float, bins: int) -> float:
        return edge * 127 / (bins - 1) + 0.5

    assert (first.top, first.left, first.bottom, first.right) == pytest.approx(
        (on_grid(9.5, 64), on_grid(3.5, 32), on_grid(19.5, 64), on_grid(7.5, 32)))
    assert (second.top, second.left, second.bottom, second.right) == pytest.approx(
        (on_grid(39.5, 64), on_grid(19.5, 32), on_grid(45.5, 64), on_grid(29.5, 32)))
    assert mask_boxes(np.zeros((64, 32), np.uint8), frame, (128, 128)) == []
    with pytest.raises(ConfigError, match="does not match"):
        mask_boxes(np.zeros((10, 10), np.uint8), frame, (128, 128))


def test_a_sine_spaced_frame_and_a_png_export_of_the_same_bins_look_alike_to_the_detector() -> None:
    # The simulator's beams are equally spaced in sine (as the sensor's beamformer lays them); a real PNG export
    # has no bearing table, so its columns are beam indices. The same bins must land on the same detector cells.
    mask = np.zeros((64, 64), np.uint8)
    mask[20:30, 28:36] = 1  # near boresight, where sine spacing is densest
    simulated = _frame(64, np.arcsin(np.linspace(-0.9, 0.9, 64))).replace(intensity=mask.astype(np.float32))
    exported = _frame(64, np.linspace(-1.1, 1.1, 64)).replace(intensity=mask.astype(np.float32))
    np.testing.assert_allclose(detector_image(simulated, (128, 128)), detector_image(exported, (128, 128)), atol=1e-6)
    assert mask_boxes(mask, simulated, (128, 128)) == mask_boxes(mask, exported, (128, 128))
    rows, cols = np.nonzero(detector_image(simulated, (128, 128)) > 0.5)
    (box,) = mask_boxes(mask, simulated, (128, 128))
    assert box.top == pytest.approx(rows.min(), abs=1.5) and box.bottom == pytest.approx(rows.max() + 1, abs=1.5)
    assert box.left == pytest.approx(cols.min(), abs=1.5) and box.right == pytest.approx(cols.max() + 1, abs=1.5)


def test_yolo_labels_parse_onto_the_grid(tmp_path: Path) -> None:
    labels = tmp_path / "labels" / "a.txt"
    labels.parent.mkdir()
    labels.write_text("0 0.5 0.25 0.25 0.125\n\n3 0.1 0.9 0.2 0.2\n")
    boxes = read_yolo_boxes(labels, (128, 64))
    assert boxes[0] == Box(top=24.0, left=24.0, bottom=40.0, right=40.0)
    assert (boxes[1].top, boxes[1].left, boxes[1].bottom, boxes[1].right) == pytest.approx((102.4, 0.0, 128.0, 12.8))
    assert yolo_label_file(tmp_path / "images" / "a.png") == labels


@pytest.mark.parametrize("bad_line", ["0 0.5 0.5 0.1", "0 0.5 x 0.1 0.1", "0 0.5 0.5 0 0.1", "0 1.5 0.5 0.1 0.1"])
def test_a_bad_yolo_line_names_the_file_and_line(tmp_path: Path, bad_line: str) -> None:
    labels = tmp_path / "frame_7.txt"
    labels.write_text(f"0 0.5 0.5 0.1 0.1\n{bad_line}\n")
    with pytest.raises(FormatError, match="line 2") as caught:
        read_yolo_boxes(labels, (128, 128))
    assert caught.value.source == str(labels) and caught.value.field == "line 2"
    with pytest.raises(FormatError, match="cannot read"):
        read_yolo_boxes(tmp_path / "missing.txt", (128, 128))


def test_real_held_out_labels_parse_one_box_per_frame(real_oculus: Path) -> None:
    files = oculus_recording_files(OCULUS_HELD_OUT_RECORDING, real_oculus.parents[2])
    assert len(files) == 89
    boxes = [read_yolo_boxes(yolo_label_file(path), (128, 128)) for path in files]
    assert all(len(frame_boxes) >= 1 for frame_boxes in boxes)
    assert all(0 <= b.left < b.right <= 128 and b.top < b.bottom for frame_boxes in boxes for b in frame_boxes)


def test_augmented_boxes_follow_the_moved_target() -> None:
    image = np.zeros((64, 64), np.float32)
    image[20:30, 8:24] = 1.0
    rng = np.random.default_rng(0)
    kept = 0
    for _ in range(20):
        moved, boxes = augment(image, [Box(20, 8, 30, 24)], DetectorConfig(gamma_jitter=0.0), rng)
        rows, cols = np.nonzero(moved > 0.5)
        if not boxes:  # pushed mostly off the frame
            continue
        kept += 1
        (box,) = boxes
        assert (box.top, box.left, box.bottom, box.right) == pytest.approx(
            (rows.min(), cols.min(), rows.max() + 1, cols.max() + 1), abs=1.0)
    assert kept >= 10


def _blob_frames(n: int, grid: tuple[int, int], seed: int) -> tuple[np.ndarray, list[list[Box]]]:
    """Speckle-like background with one or two bright rectangles of random size, and their boxes."""
    rng = np.random.default_rng(seed)
    images = (0.25 * rng.random((n, *grid))).astype(np.float32)
    boxes = []
    for image in images:
        frame_boxes = []
        for _ in range(rng.integers(1, 3)):
            height, width = rng.integers(5, 14, 2)
            top, left = rng.integers(0, grid[0] - height), rng.integers(0, grid[1] - width)
            image[top:top + height, left:left + width] = 0.7 + 0.3 * rng.random((height, width))
            frame_boxes.append(Box(float(top), float(left), float(top + height), float(left + width)))
        boxes.append(frame_boxes)
    return images, boxes


def test_detector_trained_on_bright_blobs_finds_them() -> None:
    config = DetectorConfig(grid=(64, 64), channels=16, steps=200, learning_rate=1e-2)
    images, boxes = _blob_frames(64, config.grid, seed=0)
    detector = train_detector(images, boxes, config)
    test_images, test_boxes = _blob_frames(24, config.grid, seed=1)
    predictions = detect(detector, test_images)
    assert all(len(frame) <= config.max_detections for frame in predictions)
    assert average_precision(predictions, test_boxes) > 0.5


def test_detector_rejects_bad_config_and_frames() -> None:
    with pytest.raises(ConfigError, match="multiples"):
        DetectorConfig(grid=(130, 128))
    with pytest.raises(ConfigError, match="learning_rate"):
        DetectorConfig(learning_rate=0.0)
    with pytest.raises(ConfigError, match="multiple of 8"):
        DetectorConfig(channels=12)
    config = DetectorConfig(grid=(32, 32), channels=8, steps=1)
    with pytest.raises(ConfigError, match="frames must be"):
        train_detector(np.zeros((2, 16, 16), np.float32), [[], []], config)
    with pytest.raises(ConfigError, match="box lists"):
        train_detector(np.zeros((2, 32, 32), np.float32), [[]], config)
