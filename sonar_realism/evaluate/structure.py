"""Does a translation keep the simulated scene? Edge SSIM against the sim input and object-mask IoU.

Realism scores alone reward a translator that paints a plausible real seabed and forgets the input;
these two numbers catch that. Both work on model grids (float32 [rows, cols] in [0, 1]).
* edge SSIM: SSIM between the gradient-magnitude maps of input and output after a Gaussian blur that
  suppresses speckle (texture is supposed to change; object outlines and shadows are not).
* mask IoU: the simulator knows which cells hold an object; the same number of brightest cells of the
  blurred output should fall on them.
"""

from __future__ import annotations

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


def mask_iou(mask: np.ndarray, output: np.ndarray) -> float:
    """IoU of the object mask with the equally many brightest cells of the blurred output (NaN: no object)."""
    if mask.shape != output.shape:
        raise ConfigError(f"mask_iou: shapes differ {mask.shape} vs {output.shape}")
    truth = mask > 0
    area = int(truth.sum())
    if area == 0:
        return float("nan")
    smooth = cv2.GaussianBlur(output.astype(np.float32), (0, 0), SPECKLE_BLUR_SIGMA).ravel()
    predicted = np.zeros(smooth.size, bool)
    predicted[np.argpartition(-smooth, area - 1)[:area]] = True
    predicted = predicted.reshape(truth.shape)
    return float((truth & predicted).sum() / (truth | predicted).sum())


def mask_to_grid(mask: np.ndarray, frame: SonarImage, grid: tuple[int, int]) -> np.ndarray:
    """An object mask [n_ranges, n_beams] of `frame` on the model grid, through the frame's own range and
    bearing tables as the frame itself is (Oculus beams are not evenly spaced), thresholded to stay binary."""
    if mask.shape != (frame.n_ranges, frame.n_beams):
        raise ConfigError(f"mask_to_grid: mask shape {mask.shape} is not the frame's {(frame.n_ranges, frame.n_beams)}")
    as_frame = frame.replace(intensity=(mask > 0).astype(np.float32), intensity_scale=1.0)
    return (resample_to_grid(as_frame, *grid).intensity >= 0.5).astype(np.uint8)
