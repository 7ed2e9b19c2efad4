"""Downstream detection: does training on translated frames find real targets better than training on raw sim?

A small CenterNet-style detector (Zhou et al. 2019, "Objects as Points") for polar frames on the model grid
(float32 [rows = range, cols = beams] in [0, 1], see `sonar_realism.models.datasets.to_model_grid`), one class:
* a few convolutions down to stride 4, dilated to see a target and its shadow together;
* a centre heatmap head trained with the CenterNet focal loss against Gaussians at the box centres, a box-size
  head (log height and width in grid cells) and a sub-cell offset head, both trained at the centre cells only;
* detections are the local maxima of the heatmap (3 x 3), highest first.

Frames go onto the detector grid in bin order (`detector_image`): rows are range bins, columns beam indices,
whatever bearing table a frame carries. The real Oculus exports are PNGs without one, so their columns are beam
indices; the simulator lays its beams equally in sin(bearing) as the sensor does, and resampling its frames to
equal angles would draw a target near boresight 0.8 x as wide as the same target in a real export.

Boxes are in grid cells, continuous coordinates (cell i spans [i, i + 1)). Training boxes come from the
simulator's object masks (`mask_boxes`) or from YOLO label files (`read_yolo_boxes`); the score is VOC-style
all-point average precision at one IoU threshold (`average_precision`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.io.yolo import read_yolo_labels
from sonar_realism.models.datasets import to_model_grid

STRIDE = 4  # grid cells per heatmap cell
_HEATMAP_PRIOR = 0.01  # initial foreground probability of every heatmap cell (CenterNet's bias init)


@dataclass(frozen=True)
class Box:
    """An axis-aligned box on the model grid, in cells: rows are range, columns are beams."""

    top: float
    left: float
    bottom: float
    right: float

    @property
    def area(self) -> float:
        return max(0.0, self.bottom - self.top) * max(0.0, self.right - self.left)

    def iou(self, other: Box) -> float:
        rows = min(self.bottom, other.bottom) - max(self.top, other.top)
        cols = min(self.right, other.right) - max(self.left, other.left)
        overlap = max(0.0, rows) * max(0.0, cols)
        union = self.area + other.area - overlap
        return overlap / union if union > 0 else 0.0

    def clipped(self, grid: tuple[int, int]) -> Box:
        return Box(min(max(self.top, 0.0), grid[0]), min(max(self.left, 0.0), grid[1]),
                   min(max(self.bottom, 0.0), grid[0]), min(max(self.right, 0.0), grid[1]))


class Detection(NamedTuple):
    box: Box
    score: float


@dataclass(frozen=True)
class DetectorConfig:
    """Model size, training schedule and decoding of the detector."""

    grid: tuple[int, int] = (128, 128)
    channels: int = 16
    dilations: tuple[int, ...] = (1, 2, 4)  # the 3 x 3 convolutions at stride 4
    steps: int = 1000
    batch_size: int = 16
    learning_rate: float = 5e-3
    size_weight: float = 1.0  # weight of the log-size and offset L1 losses against the focal loss
    # Augmentation, the same for every training set: random port/starboard mirrors (a physically valid frame;
    # a range flip is not), zooms by up to `max_zoom` either way about a random point (targets come in many
    # sizes), and gamma changes by up to exp(+-gamma_jitter) (gain and contrast differ between recordings).
    flip_beams: bool = True
    max_zoom: float = 1.5
    gamma_jitter: float = 0.4
    max_detections: int = 10  # per frame
    seed: int = 0

    def __post_init__(self) -> None:
        if len(self.grid) != 2 or min(self.grid) < STRIDE or any(g % STRIDE for g in self.grid):
            raise ConfigError(f"detector grid: two sizes, multiples of {STRIDE}, got {self.grid}")
        if self.channels < 8 or self.channels % 8 or self.steps < 1 or self.batch_size < 1 or self.max_detections < 1:
            raise ConfigError(f"detector: channels a multiple of 8 (GroupNorm of 4 groups at half width), steps, "
                              f"batch_size and max_detections >= 1 needed, got {self}")
        if not self.learning_rate > 0 or not self.size_weight >= 0 or any(d < 1 for d in self.dilations):
            raise ConfigError(f"detector: learning_rate > 0, size_weight >= 0, dilations >= 1 needed, got {self}")
        if not self.max_zoom >= 1 or not self.gamma_jitter >= 0:
            raise ConfigError(f"detector: max_zoom >= 1 and gamma_jitter >= 0 needed, got {self}")


def _conv(inputs: int, outputs: int, kernel: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    padding = dilation * (kernel // 2)
    return nn.Sequential(nn.Conv2d(inputs, outputs, kernel, stride, padding, dilation, bias=False),
                         nn.GroupNorm(4, outputs), nn.ReLU(inplace=True))


class CenterNet(nn.Module):
    """[B, 1, R, C] frames -> heatmap logits [B, 1, R/4, C/4], log size and offset [B, 2, R/4, C/4] each."""

    def __init__(self, config: DetectorConfig) -> None:
        super().__init__()
        width = config.channels
        self.body = nn.Sequential(_conv(1, width // 2, 5, stride=2), _conv(width // 2, width, 3, stride=2),
                                  *[_conv(width, width, 3, dilation=d) for d in config.dilations])
        self.heatmap = nn.Conv2d(width, 1, 1)
        self.log_size = nn.Conv2d(width, 2, 1)
        self.offset = nn.Conv2d(width, 2, 1)
        nn.init.constant_(self.heatmap.bias, -math.log((1 - _HEATMAP_PRIOR) / _HEATMAP_PRIOR))

    def forward(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        features = self.body(frames)
        return self.heatmap(features), self.log_size(features), self.offset(features)


@dataclass
class Detector:
    """A trained detector and the config it was trained with."""

    model: CenterNet
    config: DetectorConfig


# --- boxes from the simulator's masks and from YOLO labels ----------------------------------------------------------

def in_bin_order(frame: SonarImage) -> SonarImage:
    """`frame` with equally spaced ranges and bearings over its own span: on any grid, bin i of each axis lands
    where bin i of a frame without tables (a PNG export) lands."""
    return frame.replace(ranges_m=np.linspace(frame.ranges_m[0], frame.ranges_m[-1], frame.n_ranges),
                         azimuths_rad=np.linspace(frame.azimuths_rad[0], frame.azimuths_rad[-1], frame.n_beams))


def detector_image(frame: SonarImage, grid: tuple[int, int]) -> np.ndarray:
    """A 2-D frame as the detector sees it: in bin order, on `grid`, scaled to its maximum (float32 [0, 1])."""
    return to_model_grid(in_bin_order(frame), grid, "frame_max")


def mask_boxes(mask: np.ndarray, frame: SonarImage, grid: tuple[int, int]) -> list[Box]:
    """One box per object id > 0 of a simulator mask [n_ranges, n_beams] (uint8 ids on `frame`'s own bins),
    on the grid `detector_image` puts `frame` on."""
    if mask.shape != (frame.n_ranges, frame.n_beams):
        raise ConfigError(f"mask_boxes: mask {mask.shape} does not match the frame ({frame.n_ranges}, "
                          f"{frame.n_beams})")
    boxes = []
    for object_id in np.unique(mask):
        if object_id == 0:
            continue
        rows, cols = np.nonzero(mask == object_id)
        top, bottom = _bin_edges_on_grid(mask.shape[0], rows.min(), rows.max(), grid[0])
        left, right = _bin_edges_on_grid(mask.shape[1], cols.min(), cols.max(), grid[1])
        boxes.append(Box(top, left, bottom, right))
    return boxes


def _bin_edges_on_grid(n_bins: int, first: int, last: int, n_grid: int) -> tuple[float, float]:
    """The outer edges of bins first..last of an axis of n_bins, in cells of an n_grid grid whose cell centres
    run from bin 0's centre to bin n_bins - 1's (as `resample_to_grid` lays them)."""
    if n_bins < 2:
        raise ConfigError(f"mask_boxes: an axis of {n_bins} bin spans no distance")
    scale = (n_grid - 1) / (n_bins - 1)
    return (first - 0.5) * scale + 0.5, (last + 0.5) * scale + 0.5


def read_yolo_boxes(path: str | Path, grid: tuple[int, int]) -> list[Box]:
    """The boxes of a YOLO label file (io/yolo.py; rows = range, columns = beams), on the model grid. Every class
    counts as "object"."""
    rows, cols = grid
    return [Box((y.cy - y.height / 2) * rows, (y.cx - y.width / 2) * cols, (y.cy + y.height / 2) * rows,
                (y.cx + y.width / 2) * cols) for y in read_yolo_labels(path)]


# --- training -------------------------------------------------------------------------------------------------------

def _targets(boxes: list[Box], grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Heatmap [h, w], log size [2, h, w], offset [2, h, w] and centre-cell weight [h, w] for one frame."""
    height, width = grid[0] // STRIDE, grid[1] // STRIDE
    heatmap = np.zeros((height, width), np.float32)
    log_size = np.zeros((2, height, width), np.float32)
    offset = np.zeros((2, height, width), np.float32)
    centres = np.zeros((height, width), np.float32)
    rows, cols = np.arange(height)[:, None], np.arange(width)[None, :]
    for box in boxes:
        centre_row = 0.5 * (box.top + box.bottom) / STRIDE
        centre_col = 0.5 * (box.left + box.right) / STRIDE
        row, col = min(int(centre_row), height - 1), min(int(centre_col), width - 1)
        box_rows, box_cols = max(box.bottom - box.top, 1e-3), max(box.right - box.left, 1e-3)
        # An elliptical Gaussian as wide as a sixth of the box (TTFNet), never narrower than half a cell.
        sigma_rows, sigma_cols = max(box_rows / STRIDE / 6, 0.5), max(box_cols / STRIDE / 6, 0.5)
        blob = np.exp(-((rows - row) ** 2 / (2 * sigma_rows ** 2) + (cols - col) ** 2 / (2 * sigma_cols ** 2)))
        np.maximum(heatmap, blob.astype(np.float32), out=heatmap)
        log_size[:, row, col] = np.log([box_rows, box_cols])
        offset[:, row, col] = (centre_row - row, centre_col - col)
        centres[row, col] = 1.0
    return heatmap, log_size, offset, centres


def augment(image: np.ndarray, boxes: list[Box], config: DetectorConfig,
             rng: np.random.Generator) -> tuple[np.ndarray, list[Box]]:
    """A randomly mirrored, zoomed and gamma-changed copy of a frame and its boxes (those still on it)."""
    rows, cols = image.shape
    zoom = float(np.exp(rng.uniform(-np.log(config.max_zoom), np.log(config.max_zoom))))
    centre_row, centre_col = rng.uniform(0, rows), rng.uniform(0, cols)
    # In box coordinates: x' = scale * x + shift per axis; a mirror (x -> cols - x) comes before the zoom.
    if config.flip_beams and rng.random() < 0.5:
        col_scale, col_shift = -zoom, zoom * (cols - centre_col) + centre_col
    else:
        col_scale, col_shift = zoom, centre_col * (1 - zoom)
    row_scale, row_shift = zoom, centre_row * (1 - zoom)
    # cv2 puts pixel centres at integers, boxes at half-integers: shift by (scale - 1) / 2 to match.
    warp = np.array([[col_scale, 0.0, col_shift + 0.5 * (col_scale - 1)],
                     [0.0, row_scale, row_shift + 0.5 * (row_scale - 1)]], np.float32)
    out = cv2.warpAffine(image, warp, (cols, rows), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    out = np.clip(out, 0.0, 1.0) ** np.float32(np.exp(rng.uniform(-config.gamma_jitter, config.gamma_jitter)))
    moved = []
    for box in boxes:
        left, right = sorted((col_scale * box.left + col_shift, col_scale * box.right + col_shift))
        shifted = Box(row_scale * box.top + row_shift, left, row_scale * box.bottom + row_shift, right)
        visible = shifted.clipped((rows, cols))
        # A target mostly pushed off the frame is no longer one to find.
        if visible.area >= 0.5 * shifted.area > 0:
            moved.append(visible)
    return out.astype(np.float32, copy=False), moved


def focal_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (alpha 2, beta 4), normalised by the number of centres."""
    probability = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    is_centre = target >= 1.0
    positive = -((1 - probability) ** 2 * torch.log(probability))[is_centre].sum()
    negative = -((1 - target) ** 4 * probability ** 2 * torch.log(1 - probability))[~is_centre].sum()
    return (positive + negative) / is_centre.sum().clamp(min=1)


def train_detector(images: np.ndarray, boxes: list[list[Box]], config: DetectorConfig) -> Detector:
    """Train from scratch on frames [N, rows, cols] (float32 in [0, 1], on `config.grid`) and their boxes.

    Deterministic for a given config (seed) and data on one thread; frames without boxes teach the background."""
    images = np.asarray(images, np.float32)
    if images.ndim != 3 or tuple(images.shape[1:]) != tuple(config.grid):
        raise ConfigError(f"train_detector: frames must be [N, {config.grid[0]}, {config.grid[1]}], got {images.shape}")
    if len(boxes) != len(images) or len(images) == 0:
        raise ConfigError(f"train_detector: {len(images)} frames but {len(boxes)} box lists")
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    model = CenterNet(config)
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.learning_rate, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, config.learning_rate, total_steps=config.steps,
                                                   pct_start=0.1)
    model.train()
    for _ in range(config.steps):
        chosen = rng.integers(0, len(images), config.batch_size)
        augmented = [augment(images[i], boxes[i], config, rng) for i in chosen]
        batch = np.stack([image for image, _ in augmented])
        targets = [_targets(frame_boxes, config.grid) for _, frame_boxes in augmented]
        heatmap, log_size, offset, centres = (torch.from_numpy(np.stack(parts)) for parts in zip(*targets, strict=True))
        heatmap_logits, predicted_size, predicted_offset = model(torch.from_numpy(batch).unsqueeze(1))
        weight = centres.unsqueeze(1)
        regression = ((F.l1_loss(predicted_size, log_size, reduction="none")
                       + F.l1_loss(predicted_offset, offset, reduction="none")) * weight).sum()
        loss = focal_loss(heatmap_logits[:, 0], heatmap) + config.size_weight * regression / weight.sum().clamp(min=1)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
    return Detector(model.eval(), config)


# --- detection and scoring ------------------------------------------------------------------------------------------

@torch.no_grad()
def detect(detector: Detector, images: np.ndarray, batch_size: int = 32) -> list[list[Detection]]:
    """Detections per frame (frames [N, rows, cols] on the detector's grid), highest score first."""
    images = np.asarray(images, np.float32)
    if images.ndim != 3 or tuple(images.shape[1:]) != tuple(detector.config.grid):
        raise ConfigError(f"detect: frames must be [N, {detector.config.grid[0]}, {detector.config.grid[1]}], "
                          f"got {images.shape}")
    out: list[list[Detection]] = []
    for start in range(0, len(images), batch_size):
        logits, log_size, offset = detector.model(torch.from_numpy(images[start:start + batch_size]).unsqueeze(1))
        heatmap = torch.sigmoid(logits)
        peaks = heatmap * (F.max_pool2d(heatmap, 3, stride=1, padding=1) == heatmap)
        width = peaks.shape[-1]
        scores, cells = peaks.flatten(1).topk(min(detector.config.max_detections, peaks[0].numel()), dim=1)
        for index in range(peaks.shape[0]):
            frame_detections = []
            for score, cell in zip(scores[index].tolist(), cells[index].tolist(), strict=True):
                if score <= 0:
                    continue
                row, col = divmod(cell, width)
                centre_row = (row + float(offset[index, 0, row, col])) * STRIDE
                centre_col = (col + float(offset[index, 1, row, col])) * STRIDE
                rows, cols = (math.exp(min(float(v), 10.0)) for v in log_size[index, :, row, col])
                frame_detections.append(Detection(Box(centre_row - rows / 2, centre_col - cols / 2,
                                                      centre_row + rows / 2, centre_col + cols / 2), score))
            out.append(frame_detections)
    return out


def average_precision(predictions: list[list[Detection]], ground_truth: list[list[Box]], iou: float = 0.5) -> float:
    """VOC-style all-point average precision of one class over frames (PASCAL VOC 2010 onwards).

    Detections of all frames are ranked by score; each is a true positive when its best-overlapping ground-truth
    box of the same frame reaches `iou` and was not claimed by a higher-scored detection. AP is the area under
    the precision-recall curve with precision made monotone. No ground truth at all: ConfigError (AP is undefined)."""
    if len(predictions) != len(ground_truth):
        raise ConfigError(f"average_precision: {len(predictions)} prediction lists for {len(ground_truth)} frames")
    if not 0.0 < iou <= 1.0:
        raise ConfigError(f"average_precision: iou must be in (0, 1], got {iou}")
    n_truth = sum(len(frame_boxes) for frame_boxes in ground_truth)
    if n_truth == 0:
        raise ConfigError("average_precision: no ground-truth boxes, AP is undefined")
    ranked = sorted(((detection.score, frame, detection.box) for frame, frame_detections in enumerate(predictions)
                     for detection in frame_detections), key=lambda item: -item[0])
    claimed = [np.zeros(len(frame_boxes), bool) for frame_boxes in ground_truth]
    hits = np.zeros(len(ranked), bool)
    for rank, (_, frame, box) in enumerate(ranked):
        overlaps = [box.iou(truth) for truth in ground_truth[frame]]
        if not overlaps:
            continue
        best = int(np.argmax(overlaps))
        if overlaps[best] >= iou and not claimed[frame][best]:
            claimed[frame][best] = True
            hits[rank] = True
    true_positives = np.cumsum(hits)
    recall = np.concatenate([[0.0], true_positives / n_truth, [1.0]])
    precision = np.concatenate([[0.0], true_positives / np.arange(1, len(ranked) + 1), [0.0]])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.flatnonzero(recall[1:] != recall[:-1])
    return float(np.sum((recall[steps + 1] - recall[steps]) * precision[steps + 1]))
