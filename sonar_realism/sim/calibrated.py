"""Frames of a calibrated sensor: every frame a new view drawn from what CALIB.json says about the setting.

Per frame (all from `seed` and the frame index): a grid the sensor used (by its share of the recording), the
sonar's height and tilt (calibrated mean plus heave/pitch spread), a fresh seabed patch with the calibrated
patchiness, and, as often as the recording shows one, a target (sphere, cube or barrel) of the recording's size
at the recording's range, anywhere across the central fan. The clean render goes through the calibrated
effect chain, the residual gain, and the recording's export (per-frame max to 255 when it had one).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterator, Sequence
from typing import Any

import cv2
import numpy as np

from sonar_realism.frames import SonarImage, uniform_azimuths
from sonar_realism.parallel import parallel_imap
from sonar_realism.sim.calibration import MAX_TARGETS, Calibration, Estimate, GridMode, SeabedTerms
from sonar_realism.sim.effects import Effect, GammaQuantization, apply_effects, resolve_effects
from sonar_realism.sim.scene import Pose, Scene, Seabed, _ObjectMaker, _smooth_noise
from sonar_realism.sim.sensor import SensorConfig
from sonar_realism.sim.simulate import frame_for
from sonar_realism.sim.texture import REPLACES as TEXTURE_REPLACES
from sonar_realism.sim.texture import apply_texture, local_mean

TARGET_KINDS = ("sphere", "cube", "barrel")
# Spread of one target's size around the calibrated size (log-normal sigma) and of its range (fraction).
SIZE_SPREAD = 0.25
RANGE_SPREAD = 0.15
# A target is at most this share of the range window across: the Oculus fit recording's labelled object spans
# 0.4-0.7 of its fan, about 0.55 of the window (0.3 clipped it to half its labelled size).
SIZE_CAP = 0.75
# Targets sit within this share of the half fan around boresight (the recordings keep them in view).
BEARING_SHARE = 0.55
# Dark patches (mud, weed, holes) keep this share of the surrounding backscatter.
DARK_PATCH_LEVEL = 0.15
ELEVATION_RAYS = 64
SEABED_AMPLITUDE = 0.35
ANGLE_STEP = 2 * math.pi / 2048  # of the seabed patches' angular grid


@dataclasses.dataclass(frozen=True)
class SeabedLook:
    """The seabed terms a frame is drawn with (the calibration's values, or trial values during a fit)."""

    patch_contrast: float
    patch_scale_m: float
    patch_width_deg: float
    dark_fraction: float
    roughness_m: float

    @classmethod
    def of(cls, terms: SeabedTerms) -> SeabedLook:
        """The terms' fitted values."""
        return cls(**{f.name: getattr(terms, f.name).value for f in dataclasses.fields(cls)})

    def as_terms(self) -> SeabedTerms:
        """These values as seabed terms without an interval (a look being fitted has none yet)."""
        return SeabedTerms(**{name: Estimate(value, value, value) for name, value in dataclasses.asdict(self).items()})


def sensor_for(mode: GridMode, vertical_fov_deg: float) -> SensorConfig:
    sensor = SensorConfig(n_beams=mode.n_beams, n_ranges=mode.n_ranges, fov_deg=mode.fov_deg,
                          vertical_fov_deg=vertical_fov_deg, min_range_m=mode.min_range_m,
                          max_range_m=mode.max_range_m, elevation_rays=ELEVATION_RAYS)
    sensor.validate()
    return sensor


def make_patch(rng: np.random.Generator, extent_m: float, look: SeabedLook) -> Seabed:
    """A square seabed centred on the sensor (the origin): roughness, gentle undulation, and a log-normal albedo
    with dark patches; `look` sets the contrast, the correlation lengths along range and across the fan, and the
    dark share of the mean level."""
    spacing = max(0.04, extent_m / 640)
    n = int(math.ceil(extent_m / spacing)) + 1
    heights = (look.roughness_m * _smooth_noise(rng, (n, n), 0.15 / spacing)
               + 0.05 * _smooth_noise(rng, (n, n), 3.0 / spacing))
    albedo = np.exp(look.patch_contrast * _polar_noise(rng, n, spacing, look))
    if look.dark_fraction > 0:
        patches = _polar_noise(rng, n, spacing, look)
        threshold = np.quantile(patches[:: 4, :: 4], 1 - look.dark_fraction)
        dark = 1.0 / (1.0 + np.exp(-(patches - threshold) * 6.0))
        albedo = albedo * (1 - (1 - DARK_PATCH_LEVEL) * dark)
    # unit median: the patches vary about sand's level instead of lifting most of the seabed into the clip at 1
    albedo = albedo / float(np.median(albedo[:: 4, :: 4]))
    return Seabed(-extent_m / 2, -extent_m / 2, spacing, heights.astype(np.float32), albedo.astype(np.float32))


def _polar_noise(rng: np.random.Generator, n: int, spacing_m: float, look: SeabedLook) -> np.ndarray:
    """Zero-mean, unit-rms Gaussian field on the n x n patch centred on the sensor, correlated over
    `look.patch_scale_m` along range and `look.patch_width_deg` across the fan (a fixed angle at every range).

    Drawn on a coarse (range, world angle) grid wrapped in angle and sampled at every cell's polar coordinates.
    """
    r_max = n * spacing_m * 0.75  # past the square's corner
    sigma_r = max(look.patch_scale_m / spacing_m, 0.5)  # in range cells
    sigma_angle = max(math.radians(look.patch_width_deg) / ANGLE_STEP, 0.5)  # in angle cells
    coarse = max(1.0, min(sigma_r, sigma_angle) / 2.0)  # same field statistics, a fraction of the cost
    n_angles = int(math.ceil(2 * math.pi / ANGLE_STEP / coarse))
    white = rng.standard_normal((int(math.ceil(r_max / spacing_m / coarse)) + 2, n_angles)).astype(np.float32)
    pad = int(math.ceil(4 * sigma_angle / coarse)) + 1
    wrapped = np.pad(white, ((0, 0), (pad, pad)), mode="wrap")
    field = cv2.GaussianBlur(wrapped, (0, 0), sigmaX=sigma_angle / coarse, sigmaY=sigma_r / coarse,
                             borderType=cv2.BORDER_REFLECT_101)[:, pad:-pad]
    turns, radius = _polar_cells(n)
    out = cv2.remap(np.ascontiguousarray(field), turns * np.float32(n_angles), radius * np.float32(1 / coarse),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return (out - out.mean()) / max(float(out.std()), 1e-12)


@functools.lru_cache(maxsize=16)
def _polar_cells(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every cell of the n x n patch in polar form about its centre: angle in turns [0, 1] and radius in cells
    (one pair per grid mode's patch size)."""
    cells = np.arange(n, dtype=np.float32) - (n - 1) / 2
    x, y = np.meshgrid(cells, cells, indexing="ij")
    turns = ((np.arctan2(y, x) + math.pi) / (2 * math.pi)).astype(np.float32)
    radius = np.hypot(x, y).astype(np.float32)
    for table in (turns, radius):
        table.flags.writeable = False
    return turns, radius


def target_count(mean: float, rng: np.random.Generator) -> int:
    """How many targets a frame with targets shows: one more than a Poisson draw of mean `mean` - 1 (no draw at a
    mean of one, so calibrations of one target per frame keep their random stream)."""
    if mean <= 1.0:
        return 1
    return 1 + min(int(rng.poisson(mean - 1.0)), MAX_TARGETS - 1)


def _place_target(maker: _ObjectMaker, rng: np.random.Generator, calibration: Calibration, pose: Pose,
                  mode: GridMode) -> None:
    t = calibration.targets
    size = float(np.clip(t.size_m.value * math.exp(rng.normal(0.0, SIZE_SPREAD)), 0.05, SIZE_CAP * mode.max_range_m))
    slant = mode.max_range_m * t.range_fraction.value * (1 + rng.uniform(-RANGE_SPREAD, RANGE_SPREAD))
    slant = float(np.clip(slant, pose.z * 1.05 + size, 0.9 * mode.max_range_m))
    ground = math.sqrt(max(slant ** 2 - pose.z ** 2, 0.01))
    bearing = math.radians(mode.fov_deg / 2) * BEARING_SHARE * rng.uniform(-1.0, 1.0)
    heading = pose.yaw - bearing  # bearing is positive to starboard
    x, y = ground * math.cos(heading), ground * math.sin(heading)
    kind = TARGET_KINDS[int(rng.integers(len(TARGET_KINDS)))]
    if kind == "sphere":
        maker.sphere(x, y, radius=size / 2)
    elif kind == "cube":
        maker.box(x, y, half=(size / 2, size / 2, size / 2))
    else:
        maker.barrel(x, y, radius=size * 0.35, length=size, upright=bool(rng.random() < 0.5))


def calibrated_view(calibration: Calibration, seed: int, index: int, look: SeabedLook | None = None,
                    ) -> tuple[SonarImage, np.ndarray]:
    """The clean frame (float32 amplitude) and object mask of frame `index`: a new scene per frame."""
    rng = np.random.default_rng([seed, index, 11])
    modes = calibration.grid.modes
    mode = modes[int(rng.choice(len(modes), p=np.array([m.weight for m in modes]) / sum(m.weight for m in modes)))]
    m = calibration.mounting
    height = max(0.05, m.height_m.value + m.heave_sd_m.value * float(rng.standard_normal()))
    tilt = math.radians(m.tilt_deg.value + m.pitch_sd_deg.value * float(rng.standard_normal()))
    pose = Pose(0.0, 0.0, height, yaw=float(rng.uniform(0, 2 * math.pi)), tilt=tilt)
    seabed = make_patch(rng, 2 * (mode.max_range_m + 1.0), look or SeabedLook.of(calibration.seabed))
    maker = _ObjectMaker(seabed, rng)
    if rng.random() < calibration.targets.present_fraction.value:
        for _ in range(target_count(calibration.targets.count.value, rng)):
            _place_target(maker, rng, calibration, pose, mode)
    scene = Scene("calibrated", int(rng.integers(2 ** 31)), seabed, tuple(maker.primitives), tuple(maker.objects),
                  trajectory=lambda n: [pose] * n, trajectory_kind="calibrated",
                  shadow_floor=calibration.targets.shadow_floor)
    # unclipped: the recording's bright returns (patches, rims) keep their range until the output mapping
    frame, mask = frame_for(scene, pose, sensor_for(mode, m.vertical_fov_deg), index, clip=False)
    # The recording is rescaled per frame, so its absolute level is unknown: put the seabed at the level the
    # effect defaults assume (sand at 15 deg grazing), so signal-to-noise is the effects' to fit, not the tilt's.
    seabed = frame.intensity[(frame.intensity > 0) & (mask == 0)]
    if seabed.size:
        level = np.float32(np.clip(SEABED_AMPLITUDE / max(float(np.median(seabed)), 1e-6), 0.3, 30.0))
        gain = np.where(target_pixels(mask), np.float32(level * calibration.targets.highlight_gain), level)
        frame = frame.replace(intensity=(frame.intensity * gain).astype(np.float32))
    frame = frame.replace(meta={**frame.meta, "objects": [
        {"id": o.object_id, "kind": o.kind, "position": list(o.position), "material": o.material}
        for o in scene.objects]})
    return frame, mask


def target_pixels(mask: np.ndarray) -> np.ndarray:
    """Where a target's return lies: its mask grown by the few bins a surface element is spread over."""
    return cv2.dilate((mask > 0).astype(np.uint8), np.ones((7, 3), np.uint8)) > 0


def residual_gain(calibration: Calibration, frame: SonarImage) -> np.ndarray:
    """Amplitude gain [n_ranges, n_beams] of the calibration's residual range and bearing terms."""
    rows = np.linspace(0.0, 1.0, frame.n_ranges)
    cols = np.linspace(0.0, 1.0, frame.n_beams)
    range_db = np.interp(rows, np.linspace(0, 1, len(calibration.range_gain_db)), calibration.range_gain_db)
    bearing_db = np.interp(cols, np.linspace(0, 1, len(calibration.bearing_gain_db)), calibration.bearing_gain_db)
    return (10 ** ((range_db[:, None] + bearing_db[None, :]) / 20)).astype(np.float32)


def finish(calibration: Calibration, clean: SonarImage, chain: Sequence[Effect], rng: np.random.Generator,
           gain: bool = True) -> SonarImage:
    """Effects before the output mapping, the residual gain, the output mapping, then the recording's export.
    With a fitted texture and `speckle` in the chain, the recording's own speckle and export replace the
    catalogue's speckle: drawn on the output level, scaled to the maximum and 8-bit as the recording was."""
    return _as_exported(calibration, _finished(calibration, clean, chain, rng, gain))


def _as_exported(calibration: Calibration, frame: SonarImage) -> SonarImage:
    """An export without a bearing table (images whose columns are beam indices) reads with equal beams across
    the fan, whatever the sensor's real spacing: the simulated frame is labelled the same way, so the two reach
    any resampling (the model grid) alike. Rendering used the physical, sin-spaced table."""
    if calibration.grid.bearing_source == "recording":
        return frame
    # the reader's default: n equal beams across the span (the sensor's table spans it centre to centre)
    return frame.replace(azimuths_rad=uniform_azimuths(frame.n_beams, frame.fov_rad))


def _finished(calibration: Calibration, clean: SonarImage, chain: Sequence[Effect], rng: np.random.Generator,
              gain: bool) -> SonarImage:
    textured = calibration.texture is not None and any(e.name == "speckle" for e in chain)
    if textured:
        return apply_texture(calibration.texture, _texture_level(calibration, clean, chain, rng, gain), rng,
                             calibration.learned_texture)
    output = [e for e in chain if isinstance(e, GammaQuantization)]
    frame = _before_output(calibration, clean, chain, rng, gain)
    if output:
        frame = apply_effects(frame, output, rng)
    if calibration.export_rescaled:
        frame = _rescale_to_max(frame)
    return frame


def _before_output(calibration: Calibration, clean: SonarImage, chain: Sequence[Effect], rng: np.random.Generator,
                   gain: bool) -> SonarImage:
    """The effects before the output mapping, then the residual gain."""
    before = [e for e in chain if not isinstance(e, GammaQuantization)]
    frame = apply_effects(clean, before, rng) if before else clean
    return frame.replace(intensity=frame.intensity * residual_gain(calibration, frame)) if gain else frame


def _texture_level(calibration: Calibration, clean: SonarImage, chain: Sequence[Effect], rng: np.random.Generator,
                   gain: bool = True) -> SonarImage:
    """The frame a fitted texture is drawn on: the chain without the effects the texture replaces, on the output
    level (the texture was fitted on the export) before 8-bit saturation, so that the speckled value saturates,
    not the mean (a clipped mean would be a flat plateau under uniform speckle)."""
    chain = [e for e in chain if e.name not in TEXTURE_REPLACES]
    frame = _before_output(calibration, clean, chain, rng, gain)
    output = [e for e in chain if isinstance(e, GammaQuantization)]
    return frame.replace(intensity=output[0].level(frame.intensity)) if output else frame


def texture_levels(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int) -> list[np.ndarray]:
    """The local mean levels (`sim/texture.local_mean`, full-scale units) a fitted texture is drawn on in n
    calibrated views: what a learned texture is fitted on, unpaired against the recording."""
    levels = []
    for index in range(n):
        clean, _ = calibrated_view(calibration, seed, index)
        frame = _texture_level(calibration, clean, chain, np.random.default_rng([seed, index]))
        levels.append(local_mean(frame.intensity.astype(np.float32)))
    return levels


def _rescale_to_max(frame: SonarImage) -> SonarImage:
    """The export of the recording: raw * 255 / raw.max() per frame."""
    image = frame.intensity.astype(np.float32)
    peak = float(image.max())
    if frame.intensity.dtype == np.uint8:
        scaled = cv2.convertScaleAbs(image, alpha=255.0 / peak) if peak > 0 else frame.intensity
        return frame.replace(intensity=scaled)
    return frame.replace(intensity=image / peak if peak > 0 else image)


def calibrated_chain(calibration: Calibration, effects: str | Sequence[str] = "all",
                     params: dict[str, dict[str, Any]] | None = None) -> list[Effect]:
    """The calibrated effects named by `effects` ("all", "none", "a,b" or names), in pipeline order, with
    `params` overriding fitted values by name."""
    fitted = {effect.name: effect for effect in calibration.effect_chain()}
    return resolve_effects([fitted[effect.name] for effect in resolve_effects(effects)], params)


def simulate_calibrated(calibration: Calibration, n: int, seed: int = 0, chain: Sequence[Effect] | None = None,
                        workers: int = 1) -> Iterator[tuple[SonarImage, np.ndarray]]:
    """n (frame, object mask) pairs of the calibrated sensor, each a new randomised view (same frames whatever
    the number of worker processes)."""
    effects = list(chain) if chain is not None else calibration.effect_chain()

    def one(index: int) -> tuple[SonarImage, np.ndarray]:
        clean, mask = calibrated_view(calibration, seed, index)
        frame = finish(calibration, clean, effects, np.random.default_rng([seed, index]))
        meta: dict[str, Any] = {**frame.meta, "source": "sim-calibrated", "calibration": calibration.source}
        return frame.replace(meta=meta), mask

    yield from parallel_imap(one, range(n), workers, chunksize=2)
