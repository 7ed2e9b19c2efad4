"""The real sensor's own texture for the calibrated simulator: speckle fitted on the recording, not modelled.

The catalogue's `speckle` effect is a physical model (a complex Gaussian field times a gamma texture) with a
few parameters; a real sensor's grain also carries its beamformer's correlation across beams, per-beam
stripes, the noise floor and the export's quantisation, and a two-sample test on level-free texture patches
tells the two apart at once. So `calibrate` also fits the recording's texture with the translator's speckle
model (models/speckle.py): the ratio of each real frame to its local mean level (a Gaussian blur of one cell
of the 128 x 128 model grid, the level the cDFCVAE learns), as a level-binned quantile table plus a grain
kernel per level group, matched to the recording's neighbour correlations (`SpeckleField.match_grain`).
`simulate --calibration` then draws the simulated frame's texture from that fit in place of the `speckle`
effect, on the output level (after the output mapping): the simulated mean level, the sensor's speckle on top,
exported as the recording was.

With `calibrate --texture learned` a texture generator (models/learned_texture.py) is also trained, on the
calibrated simulator's own local mean levels against the same real frames (unpaired: it learns what the
simulated scene lacks as well as the sensor's grain), and drawn in place of the speckle model (the row gain
below stays): its weights travel inside CALIB.json.

A real sensor also varies its gain from range sample to range sample, the same across every beam of a ping
(on the Oculus set about 2.7 % rms, with bright lines in its upper tail: several per frame). The fit keeps the
part of each row mean's deviation that both halves of the fan share (the rest is speckle averaged over the
row, which the simulated speckle brings itself) as a quantile table, and each simulated row draws its gain
from it.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.models.speckle_fit import EXPORT_LEVELS, GRAIN_GROUPS, KERNEL_SIZE, LEVEL_BINS, QUANTILES, TILE

if TYPE_CHECKING:
    from sonar_realism.models.learned_texture import LearnedTexture
    from sonar_realism.models.speckle import SpeckleField

MODEL_GRID = 128  # the local mean is the level on a 128 x 128 grid, the cDFCVAE's
MIN_BLUR = 2.0  # samples
FIT_FRAMES = 96  # frames the fit uses, evenly spaced over the recording
REPLACES = ("speckle",)  # the catalogue effects the fitted texture stands in for
ROW_GAIN_QUANTILES = 33  # of log row gain, at evenly spaced probabilities from 0.5 % to 99.5 %
ROW_BASE_ROWS = 15  # a row's expected mean: the median of the row means this many rows around it
DEFAULT_LEARNED_STEPS = 2000  # critic steps of `calibrate --texture learned` (about 5 min on 2 CPU cores)


@dataclass(frozen=True)
class SensorTexture:
    """A fitted speckle model (see models/speckle.py for what each table means); `kernel` holds one grain
    kernel per group of level bins."""

    level_edges: tuple[float, ...]
    ratio_quantiles: tuple[tuple[float, ...], ...]
    kernel: tuple[tuple[tuple[float, ...], ...], ...]
    # log gain of one range row across all beams, quantiles (empty: no row gain, as in files fitted before it)
    row_gain_log_quantiles: tuple[float, ...] = ()
    # full-scale level above which the export compresses (models/speckle.compress_top); 1.0, a hard clip at full
    # scale, in files fitted before it
    export_knee: float = 1.0

    def validate(self) -> None:
        shapes = {"level_edges": ((LEVEL_BINS - 1,), np.asarray(self.level_edges, dtype=np.float64)),
                  "ratio_quantiles": ((LEVEL_BINS, QUANTILES), np.asarray(self.ratio_quantiles, dtype=np.float64)),
                  "kernel": ((GRAIN_GROUPS, KERNEL_SIZE, KERNEL_SIZE), np.asarray(self.kernel, dtype=np.float64))}
        for name, (shape, values) in shapes.items():
            if values.shape != shape or not np.isfinite(values).all():
                raise ConfigError(f"texture.{name}: expected {shape} finite numbers, got shape {values.shape}")
        if (np.diff(shapes["ratio_quantiles"][1], axis=1) < 0).any():
            raise ConfigError("texture.ratio_quantiles: each row must be non-decreasing")
        rows = np.asarray(self.row_gain_log_quantiles, dtype=np.float64)
        if rows.size not in (0, ROW_GAIN_QUANTILES) or not np.isfinite(rows).all() or (np.diff(rows) < 0).any() \
                or (np.abs(rows) > 2.0).any():
            raise ConfigError(f"texture.row_gain_log_quantiles: expected none or {ROW_GAIN_QUANTILES} non-decreasing "
                              f"finite numbers within +-2, got {rows.size}")
        if not (isinstance(self.export_knee, (int, float)) and 0.0 < self.export_knee <= 1.0):
            raise ConfigError(f"texture.export_knee: expected a number in (0, 1], got {self.export_knee!r}")


@dataclass(frozen=True)
class LearnedSensorTexture:
    """The recording's texture as a generator trained against a patch critic (models/learned_texture.py), drawn
    in place of the fitted speckle: its weights as a safetensors file, base64-encoded, so CALIB.json stays one
    self-contained file (about 0.2 MB per generator); `steps` are each generator's; `critic_loss` is the fit's last,
    averaged over the generators (2 ln 2 = 1.386: the critic at chance)."""

    safetensors_base64: str
    steps: int
    critic_loss: float

    def validate(self) -> None:
        _learned_generator(self)  # decodes and loads the weights: ConfigError on anything wrong

    @property
    def generators(self) -> int:
        """How many generators the texture draws from in turn (a mixture when more than one)."""
        return len(_learned_generator(self).generators)


@functools.lru_cache(maxsize=4)
def _learned_generator(texture: LearnedSensorTexture) -> LearnedTexture:
    from safetensors import SafetensorError
    from safetensors.torch import load

    from sonar_realism.models.learned_texture import LearnedTexture, current_state, generator_count

    try:
        weights = current_state(load(base64.b64decode(texture.safetensors_base64, validate=True)), "")
    except (binascii.Error, ValueError, SafetensorError) as exc:
        raise ConfigError(f"learned_texture.safetensors_base64: not base64 of a safetensors file ({exc})") from exc
    module = LearnedTexture(max(generator_count(weights), 1))
    try:
        module.load_state_dict(weights)
    except RuntimeError as exc:
        raise ConfigError(f"learned_texture.safetensors_base64: not this library's texture generator "
                          f"({str(exc).splitlines()[0]})") from exc
    if not module.is_fitted:
        raise ConfigError("learned_texture.safetensors_base64: the generator was never fitted")
    return module.eval()


def fit_learned_texture(images: list[np.ndarray], draw_on: list[np.ndarray], seed: int = 0,
                        steps: int = DEFAULT_LEARNED_STEPS, generators: int = 1,
                        progress: bool = False) -> LearnedSensorTexture:
    """Train the texture generator (a mixture of `generators`, side by side on the available cores) on the
    simulator's local mean levels `draw_on` (full-scale units, what `apply_texture` draws on:
    `sim/calibrated.texture_levels`) against real frames scaled to their maximum, the same frames `fit_texture`
    uses, unpaired (models/learned_texture.py)."""
    import torch
    from safetensors.torch import save

    from sonar_realism.models.device import one_thread
    from sonar_realism.models.learned_texture import LearnedTexture, TextureFitConfig

    schedule = TextureFitConfig(steps=steps)
    # the same generator from the same seed, whatever ran before it and on any thread count
    with one_thread():
        torch.manual_seed(seed)
        module = LearnedTexture(generators)
        records = module.fit(*_fit_pairs(images, schedule.crop), seed, schedule, progress, draw_on=draw_on)
    encoded = base64.b64encode(save({k: v.contiguous() for k, v in module.state_dict().items()})).decode("ascii")
    critic_loss = sum(record.critic_loss for record in records) / len(records)
    return LearnedSensorTexture(encoded, schedule.steps, round(critic_loss, 4))


@functools.lru_cache(maxsize=4)
def _speckle_field(texture: SensorTexture) -> SpeckleField:
    """The sampler of `texture`, shared by every draw of it: never changed after it is made."""
    return _new_speckle_field(texture)


def _new_speckle_field(texture: SensorTexture) -> SpeckleField:
    from sonar_realism.models.speckle import SpeckleField

    speckle = SpeckleField()
    speckle.set_fit(np.asarray(texture.level_edges), np.asarray(texture.ratio_quantiles), np.asarray(texture.kernel),
                    texture.export_knee)
    return speckle


def with_export_knee(texture: SensorTexture, images: list[np.ndarray], seed: int = 0) -> SensorTexture:
    """`texture` with its export knee matched around the local means of `images` (frames scaled to their maximum),
    as `fit_texture` matches it: for a texture fitted before the knee existed."""
    knee = _new_speckle_field(texture).match_export_knee(*_fit_pairs(images), seed)
    return dataclasses.replace(texture, export_knee=_rounded(np.array([knee]))[0])


def local_mean(image: np.ndarray) -> np.ndarray:
    """The frame's level: a Gaussian blur of one model-grid cell along range and across beams, and at least
    MIN_BLUR samples (a smaller frame's cell is finer than the speckle grain the ratio must keep)."""
    rows, cols = image.shape
    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigmaX=max(cols / MODEL_GRID, MIN_BLUR),
                            sigmaY=max(rows / MODEL_GRID, MIN_BLUR), borderType=cv2.BORDER_REFLECT_101)


def _rounded(values: np.ndarray) -> tuple:
    if values.ndim == 1:
        return tuple(float(f"{v:.6g}") for v in values)
    return tuple(_rounded(row) for row in values)


def _running_median(values: np.ndarray) -> np.ndarray:
    half = ROW_BASE_ROWS // 2
    padded = np.pad(values, half, mode="edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, ROW_BASE_ROWS), axis=1)


def _row_deviation(image: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(log of each row's mean over its expected mean, the rows it is taken on) of [ranges, beams]; by default
    the rows whose expected mean is not black water (where there is no gain to see)."""
    means = image.mean(axis=1)
    base = _running_median(means)
    rows = base > 0.02 if rows is None else rows
    return np.log(np.maximum(means[rows], 1e-4) / np.maximum(base[rows], 1e-3)), rows


def fit_row_gain(images: list[np.ndarray]) -> tuple[float, ...]:
    """Quantiles of the log row gain shared across the fan: the row means' deviations, shrunk about their
    median to the share that the fan's two halves have in common (their covariance over the whole row's
    variance)."""
    whole, left, right = [], [], []
    for image in images:
        half = image.shape[1] // 2
        deviation, rows = _row_deviation(image)
        whole.append(deviation)
        left.append(_row_deviation(image[:, :half], rows)[0])
        right.append(_row_deviation(image[:, half:], rows)[0])
    deviations, shared = np.concatenate(whole), np.cov(np.concatenate(left), np.concatenate(right))[0, 1]
    if deviations.size < 2 * ROW_GAIN_QUANTILES or deviations.var() <= 0:
        return ()
    quantiles = np.quantile(deviations, np.linspace(0.005, 0.995, ROW_GAIN_QUANTILES))
    centre = float(np.median(deviations))
    shrink = math.sqrt(float(np.clip(shared / deviations.var(), 0.0, 1.0)))
    return _rounded(centre + (quantiles - centre) * shrink - centre)


def _fit_frames(images: list[np.ndarray], side: int) -> list[np.ndarray]:
    """FIT_FRAMES frames evenly spaced over those at least `side` samples along each axis."""
    usable = [image for image in images if min(image.shape) >= side]
    if not usable:
        raise ConfigError(f"texture: no frame is at least {side} x {side} samples; cannot fit the sensor's texture")
    return [usable[i] for i in np.linspace(0, len(usable) - 1, min(FIT_FRAMES, len(usable))).astype(int)]


def _fit_pairs(images: list[np.ndarray], side: int = TILE) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The frames a texture is fitted and its export knee matched on (`_fit_frames`), float32, and their local
    means."""
    chosen = [image.astype(np.float32) for image in _fit_frames(images, side)]
    return chosen, [local_mean(image) for image in chosen]


def fit_texture(images: list[np.ndarray], seed: int = 0) -> SensorTexture:
    """Fit on real frames scaled to their maximum, [ranges, beams] at the sensor's resolution."""
    chosen, means = _fit_pairs(images)
    from sonar_realism.models.speckle import SpeckleField

    speckle = SpeckleField()
    speckle.fit(chosen, means, seed)
    texture = SensorTexture(_rounded(speckle.level_edges.numpy()), _rounded(speckle.ratio_quantiles.numpy()),
                            _rounded(speckle.kernel.numpy()), fit_row_gain(chosen),
                            _rounded(speckle.export_knee.numpy()[None])[0])
    texture.validate()
    return texture


def apply_texture(texture: SensorTexture, frame: SonarImage, rng: np.random.Generator,
                  learned: LearnedSensorTexture | None = None) -> SonarImage:
    """The frame's local mean level (the output mapping's, in full-scale units: 1.0 is 255) times a fresh draw
    of the sensor's speckle (the learned generator's where there is one), saturating at full scale, exported as
    the recording was (scaled to its maximum, 8-bit)."""
    import torch

    from sonar_realism.models.speckle import as_sensor_bytes

    level = local_mean(frame.intensity.astype(np.float32))
    generator = torch.Generator().manual_seed(int(rng.integers(0, 2 ** 62)))
    row_gain = None
    if texture.row_gain_log_quantiles:
        table = np.asarray(texture.row_gain_log_quantiles, dtype=np.float32)
        row_gain = np.exp(np.interp(rng.random(level.shape[0]), np.linspace(0.0, 1.0, table.size), table))
    field = _learned_generator(learned) if learned is not None else _speckle_field(texture)
    sample = field.sample(level[None], generator, row_gain, texture.export_knee)[0]
    return frame.replace(intensity=as_sensor_bytes(sample), intensity_scale=float(EXPORT_LEVELS))
