"""Does a translation keep the simulated scene? Edge SSIM against the sim input and object-mask IoU.

Realism scores alone reward a translator that paints a plausible real seabed and forgets the input;
these two numbers catch that. Both work on model grids (float32 [rows, cols] in [0, 1]).
* edge SSIM: SSIM between the gradient-magnitude maps of input and output after a Gaussian blur that
  suppresses speckle (texture is supposed to change; object outlines and shadows are not).
* mask IoU: the simulator knows which cells hold an object; within the object's neighbourhood, the same number
  of cells that stand out most from it (brighter, or darker where the object is darker than its surroundings in
  the sim input) should fall on them. Looking only near the object keeps the measure posed when the object is
  not the brightest thing in the frame (a calibrated seabed is often brighter than its targets).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import resample_to_grid

SPECKLE_BLUR_SIGMA = 2.0  # grid cells; about the speckle grain at 128x128


def ssim(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> float:
    """Mean structural similarity (Wang et al. 2004; Gaussian window sigma 1.5) of two 2-D images."""
    if a.shape != b.shape:
        raise ConfigError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    a = a.astype(np.float64)
    b = b.astype(np.float64)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2

    def blur(x: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(x, (11, 11), 1.5)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a ** 2
    var_b = blur(b * b) - mu_b ** 2
    cov = blur(a * b) - mu_a * mu_b
    ssim_map = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
    return float(ssim_map.mean())


def edge_map(image: np.ndarray) -> np.ndarray:
    """Gradient magnitude of the speckle-blurred image, scaled to max 1."""
    smooth = cv2.GaussianBlur(image.astype(np.float32), (0, 0), SPECKLE_BLUR_SIGMA)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.hypot(gx, gy)
    peak = float(magnitude.max())
    return magnitude / peak if peak > 0 else magnitude


def edge_ssim(sim_input: np.ndarray, output: np.ndarray) -> float:
    return ssim(edge_map(sim_input), edge_map(output))


NEIGHBOURHOOD_MARGIN = 1.0  # the object's box is grown by this many of its own sizes on each side ...
NEIGHBOURHOOD_MIN_CELLS = 6  # ... and by at least this many cells, so a small object has surroundings


def mask_iou(mask: np.ndarray, output: np.ndarray, reference: np.ndarray | None = None) -> float:
    """IoU of the object mask with the cells of the blurred `output` that stand out most from the object's
    neighbourhood (as many as the mask has; NaN: no object). A cell stands out by its log level over the
    neighbourhood's median, in the direction the object stands out in `reference` (the translator's sim input;
    `output` itself when None), so a dark target on a bright seabed is sought as dark in the output too."""
    if mask.shape != output.shape or (reference is not None and reference.shape != output.shape):
        raise ConfigError(f"mask_iou: shapes differ: mask {mask.shape}, output {output.shape}"
                          + ("" if reference is None else f", reference {reference.shape}"))
    truth = mask > 0
    area = int(truth.sum())
    if area == 0:
        return float("nan")
    rows, cols = np.nonzero(truth)
    grow_rows = max(NEIGHBOURHOOD_MIN_CELLS, int(NEIGHBOURHOOD_MARGIN * (np.ptp(rows) + 1)))
    grow_cols = max(NEIGHBOURHOOD_MIN_CELLS, int(NEIGHBOURHOOD_MARGIN * (np.ptp(cols) + 1)))
    box = (slice(max(0, rows.min() - grow_rows), rows.max() + grow_rows + 1),
           slice(max(0, cols.min() - grow_cols), cols.max() + grow_cols + 1))
    truth = truth[box]
    standout = _log_contrast(output, box)
    polarity = (standout if reference is None else _log_contrast(reference, box))[truth].mean()
    score = (standout if polarity >= 0 else -standout).ravel()
    predicted = np.zeros(score.size, bool)
    predicted[np.argpartition(-score, area - 1)[:area]] = True
    predicted = predicted.reshape(truth.shape)
    return float((truth & predicted).sum() / (truth | predicted).sum())


def _log_contrast(image: np.ndarray, box: tuple[slice, slice]) -> np.ndarray:
    """Log level of the speckle-blurred image over the median of `box`, inside `box` (one 8-bit step of floor).
    Only the box and the blur's reach around it are blurred: the same values as blurring the whole frame."""
    reach = math.ceil(4 * SPECKLE_BLUR_SIGMA) + 1  # OpenCV's kernel for float images reaches 4 sigma
    rows, cols = box
    top, left = max(0, rows.start - reach), max(0, cols.start - reach)
    crop = image[top:rows.stop + reach, left:cols.stop + reach].astype(np.float32)
    smooth = cv2.GaussianBlur(crop, (0, 0), SPECKLE_BLUR_SIGMA)[rows.start - top:rows.stop - top,
                                                                 cols.start - left:cols.stop - left]
    return np.log(smooth + 1 / 255) - np.log(float(np.median(smooth)) + 1 / 255)


def mask_to_grid(mask: np.ndarray, frame: SonarImage, grid: tuple[int, int]) -> np.ndarray:
    """An object mask [n_ranges, n_beams] of `frame` on the model grid, through the frame's own range and
    bearing tables as the frame itself is (Oculus beams are not evenly spaced), thresholded to stay binary."""
    if mask.shape != (frame.n_ranges, frame.n_beams):
        raise ConfigError(f"mask_to_grid: mask shape {mask.shape} is not the frame's {(frame.n_ranges, frame.n_beams)}")
    as_frame = frame.replace(intensity=(mask > 0).astype(np.float32), intensity_scale=1.0)
    return (resample_to_grid(as_frame, *grid).intensity >= 0.5).astype(np.uint8)
