"""`sonar-realism calibrate`: fit the simulator to one sensor in one setting from its recording alone.

    sonar-realism calibrate --real PATH --out CALIB.json [--report REPORT.html] [--match TEXT]
                            [--targets-from FOLDER ... [--target-classes IDS]]

PATH is anything `read_frames` reads (a recording, a folder of polar PNGs, the ARIS Cartesian fan set). In order:

1. the grid: beams, bearing span, range window and bins, per frame (the grids seen and their shares); a PNG
   export without a bearing table or range window gets a documented default span / bin size, said in `notes`;
2. the mounting: per frame, the height and tilt that put a flat seabed's first return (the lower edge of the
   vertical aperture) where the frame's seabed onset is, across the fan (its curvature gives the tilt); the
   median is the mounting, the spread the heave/pitch; then the height is corrected so the simulated onset
   lands on the real one (the same detector on both);
3. the seabed: its roughness (`_match_relief`: no more relief shadow than the recording's dark seabed allows),
   then patch contrast, correlation length and dark share of the mean level, matched by simulation (the
   targets' beams left out on both sides: `measure.target_beams`);
   targets: how often a shadow shows behind a return, its width (the target's size) and where it starts, then
   (under the final chain and mounting) the share and return gain that make the same detector find them as
   often and as bright in simulation (`match_shadow_targets`: it misses targets and takes some seabed for
   one); or, with `--targets-from`, the recording's own annotations (sim/annotations.py: YOLO boxes or
   class-id masks): how many frames show a target, how many each shows, their width across the fan, range and
   return; either way how deep their shadows are (`measure.shadow_level`), matched by the share of the seabed's
   power the renderer leaves there (`match_shadow_floor`);
4. the effects: a pattern search over every parameter the effect classes mark as calibrated, on frames of
   the calibrated setting (fingerprint in sim/fingerprint.py);
5. the texture: the recording's own speckle and row gain (sim/texture.py; with `--texture learned`, the
   default, also a mixture of texture generators trained on the simulated levels against the recording), which
   simulation draws in place of the catalogue's speckle; the seabed look matched again under it; then the
   near-field band (`match_near_field`: the ring-down's amplitude, decay and the receiver's rise on the band's
   own profile);
6. under the final chain and texture: the mounting again (the onset's median and its spread over frames), the
   noise floor (the TVG noise amplitude whose share of black pixels is the recording's) and the residual
   range/bearing gain; then the export knee (`match_export_knee`); with `learned`, the generator again on the
   levels so settled, and the noise floor again under it; last the seabed look on the final frames (the steps
   since its match move its measured patchiness) and the noise floor under it;
7. intervals: every number is re-estimated on bootstrap resamples of the frames (the effect parameters by a
   short local search from the fit), 5th-95th percentiles.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from sonar_realism.arguments import non_negative_int, output_file, positive_int
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.models.speckle_fit import EXPORT_KNEE_LOW, top_ratio
from sonar_realism.sim import measure
from sonar_realism.sim.annotations import (
    AnnotatedObject,
    Annotations,
    mask_objects,
    measure_objects,
    parse_classes,
    read_annotations,
)
from sonar_realism.sim.calibrated import (
    SeabedLook,
    calibrated_view,
    finish,
    simulate_calibrated,
    target_pixels,
    texture_levels,
)
from sonar_realism.sim.calibration import (
    CALIBRATION_VERSION,
    MAX_TARGETS,
    Calibration,
    Estimate,
    FittedParameter,
    Grid,
    GridMode,
    Mounting,
    SeabedTerms,
    TargetTerms,
    save_calibration,
)
from sonar_realism.sim.effects import (
    EFFECTS,
    PIPELINE_ORDER,
    Effect,
    RingDown,
    TvgNoise,
    apply_effects,
    calibrated_parameters,
)
from sonar_realism.sim.fingerprint import Fingerprint, distance, fingerprint, per_frame_rescaled, resample_profile
from sonar_realism.sim.measure import SeabedStats
from sonar_realism.sim.repeated_draws import remembering_draws
from sonar_realism.sim.sensor import oculus_bearing_table
from sonar_realism.sim.simulate import simulate
from sonar_realism.sim.texture import DEFAULT_LEARNED_STEPS, FIT_FRAMES, fit_learned_texture, fit_texture

EffectT = TypeVar("EffectT", bound=Effect)

MIN_FRAMES = 8
MIN_GRID = (16, 8)  # ranges x beams: below this a frame holds no seabed profile or texture to fit
MAX_GRID_MODES = 24
GAIN_KNOTS = 8
# Beam counts further apart than this ratio are different sensors (or modes) that need their own calibration.
MIXED_BEAMS_RATIO = 1.25
TEXTURES = ("none", "speckle", "learned")
# The noise floor is matched on the recording's share of black pixels only where it has some, within this factor
# of the amplitude the effect fit found.
MIN_BLACK_SHARE = 1e-3
FLOOR_RANGE = 16.0
# the export knee's ladder (full-scale units), bisection steps between two of its knees, and how far above the best
# fingerprint distance on the ladder a knee may be (a share of it) and still be allowed
KNEE_STEP = 0.1
KNEE_REFINE = 4
KNEE_DISTANCE_SLACK = 0.05
# The near-field band lives in the first NEAR_FIELD_SHARE of the range window (the Oculus fit recording's peaks at
# 2 % and fades by 8 %); its mean level there, in NEAR_FIELD_BINS bins, is what `match_near_field` matches.
NEAR_FIELD_SHARE = 0.12
NEAR_FIELD_BINS = 24
NEAR_FIELD_FLOOR = 0.005  # of full scale: the profiles are compared in log level above it
NEAR_FIELD_DECAYS = (0.02, 0.05, 0.1, 0.2, 0.35, 0.5)  # m: the ring-down's decay, within its PARAM_BOUNDS
NEAR_FIELD_RISES = (0.0, 0.05, 0.1, 0.2, 0.35)  # m: the receiver's rise (0: the catalogue's ring-down)
NEAR_FIELD_SECANT_STEPS = 2
NEAR_FIELD_FRAMES = 12  # views the band is matched on (a mean over beams and frames: few suffice)
# seabed roughness (m) tried by the relief match, largest first: the renderer's default down to a flat seabed
RELIEF_LADDER = (0.01, 0.007, 0.005, 0.0035, 0.0025, 0.0015, 0.001, 0.0)
SHADOW_FLOOR_STEPS = 6  # bisection steps of the shadow floor: 1/64 of the seabed's power
SHADOW_FLOOR_FRAMES = 24  # simulated frames with a target per step

# (effect, parameter, log-scale search) fitted by the calibration (declared by each effect class).
FITTED: tuple[tuple[str, str, bool], ...] = calibrated_parameters()


@dataclass(frozen=True)
class CalibrateConfig:
    """Assumptions (used only where the recording does not say) and the effort of the fit."""

    vertical_fov_deg: float = 20.0  # Oculus M1200d/M3000d class; ARIS 3000: 14
    default_fov_deg: float = 130.0  # bearing span when the recording has no bearing table
    default_range_bin_m: float = 0.02  # range bin when the recording has no range window
    sim_frames: int = 8
    # frames the final mounting match draws: the onset's spread over frames needs more than the effects' fit
    mounting_frames: int = 32
    rounds: int = 3
    bootstrap: int = 200
    effect_bootstrap: int = 4
    seed: int = 0
    # "learned": fit the recording's own speckle (sim/texture.py), then train a texture generator on the simulated
    # levels against the recording and draw it in place of the catalogue's speckle (Oculus, held out: texture
    # two-sample test 0.92 against the fitted speckle's 0.98 in the same run, docs/RESULTS.md, #11; two fits of
    # `learned_steps`, each about 12 minutes on one thread per generator); "speckle": draw the fitted speckle;
    # "none": the catalogue's speckle
    texture: str = "learned"
    learned_steps: int = DEFAULT_LEARNED_STEPS
    # the learned texture as a mixture of this many generators, each fitted on one thread from its own seed, side
    # by side: two cost one fit's time on two cores, where one left a core idle for most of `calibrate`
    learned_generators: int = 2

    def validate(self) -> None:
        ranges = {"vertical_fov_deg": (self.vertical_fov_deg, 0.5, 90.0),
                  "default_fov_deg": (self.default_fov_deg, 1.0, 179.0),
                  "default_range_bin_m": (self.default_range_bin_m, 1e-4, 1.0)}
        least = {"sim_frames": (self.sim_frames, 2), "mounting_frames": (self.mounting_frames, 2),
                 "rounds": (self.rounds, 1), "bootstrap": (self.bootstrap, 2),
                 "effect_bootstrap": (self.effect_bootstrap, 0), "learned_steps": (self.learned_steps, 1),
                 "learned_generators": (self.learned_generators, 1)}
        for name, (value, low, high) in ranges.items():
            if not low <= value <= high:
                raise ConfigError(f"calibrate: {name} must be in {low:g}..{high:g}, got {value}")
        for name, (value, low) in least.items():
            if value < low:
                raise ConfigError(f"calibrate: {name} must be {low} or more, got {value}")
        if self.texture not in TEXTURES:
            raise ConfigError(f"calibrate: texture {self.texture!r} must be one of {', '.join(TEXTURES)}")


@dataclass(frozen=True)
class CalibrationResult:
    calibration: Calibration
    real_images: list[np.ndarray]  # the recording, per-frame max scaled
    examples: dict[str, list[np.ndarray]]  # a few frames of each stage: uncalibrated, calibrated
    fingerprints: dict[str, Fingerprint]  # real and each stage


# ----------------------------------------------------------------------------------------------- the recording


def prepare_frames(frames: Sequence[SonarImage], config: CalibrateConfig) -> tuple[list[SonarImage], list[str]]:
    """Check the recording is fit to calibrate and give every frame a metric grid; notes say what was assumed."""
    if len(frames) < MIN_FRAMES:
        raise ConfigError(f"calibrate: {len(frames)} frame(s); a calibration needs at least {MIN_FRAMES} frames of "
                          "one sensor (more give tighter intervals)")
    beams = sorted({f.n_beams for f in frames})
    if beams[-1] > MIXED_BEAMS_RATIO * beams[0]:
        raise ConfigError(f"calibrate: frames of mixed sensors or modes ({beams[0]} to {beams[-1]} beams) and no way "
                          "to group them; calibrate each sensor's recording separately (e.g. --match RECORDING)")
    smallest = min(frames, key=lambda f: f.n_ranges * f.n_beams)
    if smallest.n_ranges < MIN_GRID[0] or smallest.n_beams < MIN_GRID[1]:
        raise ConfigError(f"calibrate: {smallest.meta.get('source', 'a frame')} is {smallest.n_ranges} ranges x "
                          f"{smallest.n_beams} beams; a calibration needs frames of at least {MIN_GRID[0]} x "
                          f"{MIN_GRID[1]}")
    lit = sum(1 for f in frames if np.any(f.intensity > 0))
    if lit < MIN_FRAMES:
        raise ConfigError(f"calibrate: only {lit} of {len(frames)} frame(s) hold any echo (the rest are blank); a "
                          f"calibration needs at least {MIN_FRAMES} frames with echoes")
    notes: set[str] = set()
    out = []
    for frame in frames:
        assumed = set(frame.meta.get("assumed_fields", []))
        ranges, azimuths = frame.ranges_m, frame.azimuths_rad
        if "ranges_m" in assumed:
            ranges = uniform_ranges(frame.n_ranges, frame.n_ranges * config.default_range_bin_m)
            notes.add(f"range window not in the recording: assumed {config.default_range_bin_m * 100:g} cm bins "
                      "from 0 m (height and sizes scale with this assumption; shapes do not)")
        if "azimuths_rad" in assumed:
            azimuths = oculus_bearing_table(frame.n_beams, config.default_fov_deg)
            notes.add(f"bearing table not in the recording: assumed a {config.default_fov_deg:g} deg fan, beams "
                      "equally spaced in sin(bearing) (Oculus 1.2 MHz)")
        out.append(frame.replace(ranges_m=ranges, azimuths_rad=azimuths))
    notes.add(f"vertical aperture assumed {config.vertical_fov_deg:g} deg (sensor class; not in the recording)")
    return out, sorted(notes)


def grid_of(frames: Sequence[SonarImage]) -> Grid:
    keys = Counter((f.n_beams, f.n_ranges, round(float(f.ranges_m[0] - 0.5 * _bin(f)), 3),
                    round(float(f.ranges_m[-1] + 0.5 * _bin(f)), 3), round(math.degrees(f.fov_rad), 2))
                   for f in frames)
    common = keys.most_common(MAX_GRID_MODES)
    total = sum(count for _, count in common)
    modes = tuple(GridMode(b, r, max(lo, 0.0), hi, fov, count / total) for (b, r, lo, hi, fov), count in common)
    assumed = frames[0].meta.get("assumed_fields", [])
    return Grid(modes, "default span (see notes)" if "azimuths_rad" in assumed else "recording",
                "default bin size (see notes)" if "ranges_m" in assumed else "recording")


def _bin(frame: SonarImage) -> float:
    r = frame.ranges_m
    return float(r[-1] - r[0]) / max(r.size - 1, 1)


def _estimate(values: np.ndarray, statistic: Callable[[np.ndarray], float], rng: np.random.Generator,
              resamples: int) -> Estimate:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)] if values.ndim == 1 else values
    if len(values) == 0:
        raise ConfigError("calibrate: no frame gave this measurement")
    boot = [statistic(values[rng.integers(0, len(values), len(values))]) for _ in range(resamples)]
    return Estimate(float(statistic(values)), float(np.percentile(boot, 5)), float(np.percentile(boot, 95)))


def _robust_sd(values: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def _fixed(value: float) -> Estimate:
    return Estimate(value, value, value)


# ----------------------------------------------------------------------------------------------- matching by simulation


def sim_images(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int, gain: bool = True,
               look: SeabedLook | None = None) -> list[np.ndarray]:
    return finished_images(calibration, clean_views(calibration, n, seed, look), chain, seed, gain)


def clean_views(calibration: Calibration, n: int, seed: int, look: SeabedLook | None = None) -> list[SonarImage]:
    """The first n clean calibrated frames of `seed`: what a search over export-side terms (noise floor, export
    knee) renders once and finishes under each trial."""
    return [calibrated_view(calibration, seed, index, look)[0] for index in range(n)]


def finished_images(calibration: Calibration, clean: Sequence[SonarImage], chain: Sequence[Effect], seed: int,
                    gain: bool = True) -> list[np.ndarray]:
    """`clean` through `finish` (effects, residual gain, texture, export), rescaled per frame like the recording."""
    return [per_frame_rescaled(finish(calibration, frame, chain, np.random.default_rng([seed, index]),
                                      gain=gain).intensity) for index, frame in enumerate(clean)]


def _frame_onsets(images: Sequence[np.ndarray], bins: Sequence[float]) -> np.ndarray:
    """Seabed onset (m) per frame: the median over the beam groups that show one; frames without one left out.
    Real and simulated frames are measured alike, so their onsets compare like for like."""
    return np.array([np.nanmedian(rows) * b for image, b in zip(images, bins, strict=True)
                     if np.isfinite(rows := measure.onset_rows(image)).any()])


def _scaled(estimate: Estimate, factor: float) -> Estimate:
    return Estimate(estimate.value * factor, estimate.low * factor, estimate.high * factor)


def match_onsets(calibration: Calibration, real: np.ndarray, sim: np.ndarray, spread: bool) -> Calibration:
    """Height scaled so the simulated onsets' median is the real one; with `spread`, heave and pitch scaled
    together so their spread over frames is the real one too (both move the onset, so fitting each to the
    onset's spread alone counts it twice)."""
    if len(real) < 3 or len(sim) < 3 or np.median(sim) <= 0:
        return calibration
    m = calibration.mounting
    mounting = dataclasses.replace(m, height_m=_scaled(m.height_m, float(np.median(real) / np.median(sim))))
    sim_spread = _robust_sd(sim / np.median(sim))
    if spread and sim_spread > 0:
        factor = float(np.clip(_robust_sd(real / np.median(real)) / sim_spread, 0.25, 4.0))
        mounting = dataclasses.replace(mounting, heave_sd_m=_scaled(m.heave_sd_m, factor),
                                       pitch_sd_deg=_scaled(m.pitch_sd_deg, factor))
    return dataclasses.replace(calibration, mounting=mounting)


def _seabed_table(images: Sequence[np.ndarray], targets: Sequence[np.ndarray | None]) -> np.ndarray:
    """Each frame's patchiness statistics (`SeabedStats` fields as columns; frames without a seabed left out),
    the beams `targets` marks in each frame (`measure.target_beams`) left out."""
    rows = [dataclasses.astuple(s) for s in (measure.seabed_stats(i, t) for i, t in zip(images, targets, strict=True))
            if s is not None]
    return np.array(rows, dtype=np.float64).reshape(len(rows), len(dataclasses.fields(SeabedStats)))


def _sim_seabed_table(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int, gain: bool,
                      look: SeabedLook) -> np.ndarray:
    """`_seabed_table` of the first n calibrated frames of `seed` drawn with `look`, their targets' beams (from
    the masks) left out as the recording's are."""
    images, targets = [], []
    for index in range(n):
        clean, mask = calibrated_view(calibration, seed, index, look)
        images.append(per_frame_rescaled(finish(calibration, clean, chain, np.random.default_rng([seed, index]),
                                                gain=gain).intensity))
        targets.append(measure.target_beams(mask.shape[1], [(int(o.cols.min()), int(o.cols.max()))
                                                             for o in mask_objects(mask)]))
    return _seabed_table(images, targets)


def _recording_target_beams(images: Sequence[np.ndarray], annotations: Annotations | None) -> list[np.ndarray]:
    """The beams of each recorded frame's targets: its annotated objects, or the shadow the detector finds."""
    if annotations is not None:
        spans = [[(int(o.cols.min()), int(o.cols.max())) for o in objects] for objects in annotations.objects]
    else:
        found = [measure.target_shadow(image) for image in images]
        spans = [[] if t is None else [(t.first_beam, t.first_beam + t.width_beams - 1)] for t in found]
    return [measure.target_beams(image.shape[1], s) for image, s in zip(images, spans, strict=True)]


def _seabed_summary(table: np.ndarray) -> SeabedStats:
    """The median over frames of each patchiness statistic (NaN where no frame shows a seabed)."""
    if not len(table):
        return SeabedStats(math.nan, math.nan, math.nan, math.nan)
    return SeabedStats(*(float(v) for v in np.median(table, axis=0)))


def _width_deg(stats: SeabedStats, grid: Grid) -> float:
    """The measured patch width across beams as an angle, on the grid's most common mode."""
    mode = grid.modes[0]
    return stats.width_beams * mode.fov_deg / max(mode.n_beams - 1, 1)


def _match_seabed(calibration: Calibration, chain: Sequence[Effect], look: SeabedLook, real: SeabedStats, n: int,
                  seed: int, gain: bool = False) -> SeabedLook:
    """The seabed look whose simulated patchiness (contrast, correlation lengths, dark share) is the real one's,
    by three multiplicative updates under `chain` (and the residual gain with `gain`). The width is matched only
    where the recording's patches are well wider than the measure's local box (below that the box sets the
    measure and the update would run away), and within a factor 2 of the recording's own measure."""
    measured_deg = _width_deg(real, calibration.grid)
    width_bounds = ((max(0.2, measured_deg / 2), min(60.0, measured_deg * 2)) if resolved_width(real)
                    else (look.patch_width_deg, look.patch_width_deg))
    for _ in range(3):
        sim = _seabed_summary(_sim_seabed_table(calibration, chain, n, seed, gain, look))
        if not math.isfinite(sim.contrast):
            break
        look = SeabedLook(float(np.clip(look.patch_contrast * real.contrast / max(sim.contrast, 1e-3), 0.0, 2.5)),
                          float(np.clip(look.patch_scale_m * real.scale_rows / max(sim.scale_rows, 0.5), 0.05, 20.0)),
                          float(np.clip(look.patch_width_deg * real.width_beams / max(sim.width_beams, 0.5),
                                        *width_bounds)),
                          float(np.clip(look.dark_fraction + (real.dark_fraction - sim.dark_fraction), 0.0, 0.8)),
                          look.roughness_m)
    return look


def _match_relief(calibration: Calibration, chain: Sequence[Effect], look: SeabedLook, real: SeabedStats, n: int,
                  seed: int) -> SeabedLook:
    """The look with the largest seabed roughness on RELIEF_LADDER whose relief alone (no dark patches in the
    albedo) leaves at most the recording's share of dark seabed; the look as it is where even a flat seabed
    leaves more (the dark share is then not the relief's: targets' shadows, the onset).

    At low grazing the roughness casts shadows far longer than itself (length ~ height x range / mounting
    height): the ARIS tank set, mounted 0.28 m up at 1.4-5.8 m, drew blotches 40-60 bins long from 1 cm of
    roughness where its concrete floor shows none (dark share 1.9 % against 0.5 %), and the seabed match made up
    the contrast with an albedo contrast of 0.03. The albedo's dark patches can only add dark seabed, so the
    relief is matched first, on the dark share it leaves."""
    if not math.isfinite(real.dark_fraction):
        return look
    for roughness in RELIEF_LADDER:
        trial = dataclasses.replace(look, roughness_m=roughness, dark_fraction=0.0)
        sim = _seabed_summary(_sim_seabed_table(calibration, chain, n, seed, False, trial))
        if not math.isfinite(sim.dark_fraction):
            return look
        if sim.dark_fraction <= real.dark_fraction:
            return dataclasses.replace(look, roughness_m=roughness)
    return look


def resolved_width(stats: SeabedStats) -> bool:
    """Whether the patches are wide enough across beams for the measure to see their width, not its own box."""
    return stats.width_beams >= 2 * measure.LOCAL_BOX


def effect_in(chain: Sequence[Effect], kind: type[EffectT]) -> EffectT:
    """The chain's effect of this class (a calibrated chain holds every catalogue effect once)."""
    return next(e for e in chain if isinstance(e, kind))


def match_noise_floor(calibration: Calibration, chain: Sequence[Effect], real_near_zero: float, n: int, seed: int,
                      steps: int = 8) -> list[Effect]:
    """The chain with the TVG noise amplitude whose simulated share of black pixels (at most 2 counts, drawn
    through the recording's texture and export) is the recording's: bisection in log amplitude within the
    effect's search bounds (more noise, fewer black pixels). The effect fit sets the amplitude under the
    catalogue's speckle, whose gamma tail draws black pixels at noise level by itself; the recording's texture
    draws few there, so under it the floor sat too high (Oculus: 1.8 % of pixels black against the recording's
    6.1 %). A recording with next to no black pixels (below MIN_BLACK_SHARE) does not show its floor: the chain
    is returned as it is. The search stays within a factor FLOOR_RANGE of the fitted amplitude."""
    if real_near_zero < MIN_BLACK_SHARE:
        return list(chain)
    fitted = max(effect_in(chain, TvgNoise).noise_amplitude, 1e-3)
    low, high = TvgNoise.PARAM_BOUNDS["noise_amplitude"]
    low, high = math.log(max(low, 1e-3, fitted / FLOOR_RANGE)), math.log(min(high, fitted * FLOOR_RANGE))
    clean = clean_views(calibration, n, seed)  # the noise is drawn in `finish`: the scenes stay

    def with_amplitude(log_amplitude: float) -> list[Effect]:
        return [dataclasses.replace(e, noise_amplitude=round(math.exp(log_amplitude), 5))
                if isinstance(e, TvgNoise) else e for e in chain]

    for _ in range(steps):
        middle = (low + high) / 2
        images = finished_images(calibration, clean, with_amplitude(middle), seed)
        if np.mean([measure.near_zero_fraction(i) for i in images]) > real_near_zero:
            low = middle  # too many black pixels: more noise
        else:
            high = middle
    return with_amplitude((low + high) / 2)


def near_field_profile(images: Sequence[np.ndarray]) -> np.ndarray:
    """Mean level over beams (frames scaled to their maximum) of the first NEAR_FIELD_SHARE of the range window,
    in NEAR_FIELD_BINS bins of normalised range, averaged over frames."""
    rows = [image[:max(NEAR_FIELD_BINS, round(NEAR_FIELD_SHARE * image.shape[0]))].mean(axis=1) for image in images]
    return np.mean([resample_profile(row, NEAR_FIELD_BINS) for row in rows], axis=0)


def match_near_field(calibration: Calibration, chain: Sequence[Effect], real_profile: np.ndarray, n: int,
                     seed: int) -> list[Effect]:
    """The chain with the ring-down (amplitude, decay and the receiver's rise) whose simulated near-field profile
    (`near_field_profile`, texture, gain and export included) is closest to the recording's in log level: on a
    grid of decays and rises, the amplitude that matches the band's mean log level (secant steps: the level grows
    with it), then the pair with the closest shape. The fingerprint fit sees the first rows and coarse range bins
    only, and with the catalogue's ring-down (bright at the first bin, gone in a few) it put the Oculus sim's band
    at 0.13 of full scale in the first 1 % of the range, where the recording's peaks at 0.065 at 2 % and fades by
    8 % (docs/RESULTS.md). Shape and amplitude trade off in a joint search (a short decay made up by a high
    amplitude), hence the grid."""
    clean = clean_views(calibration, min(n, NEAR_FIELD_FRAMES), seed)  # the band is added in `finish`
    ring = effect_in(chain, RingDown)
    target = np.log(real_profile + NEAR_FIELD_FLOOR)

    def with_ring(**values: float) -> list[Effect]:
        trial = dataclasses.replace(ring, **{name: float(f"{value:.3g}") for name, value in values.items()})
        return [trial if isinstance(e, RingDown) else e for e in chain]

    def tried(log_amplitude: float, decay: float, rise: float) -> tuple[float, np.ndarray, list[Effect]]:
        """Log amplitude, the simulated band's log profile and the chain, at this ring-down."""
        trial = with_ring(amplitude=math.exp(log_amplitude), decay_m=decay, rise_m=rise)
        profile = near_field_profile(finished_images(calibration, clean, trial, seed))
        return log_amplitude, np.log(profile + NEAR_FIELD_FLOOR), trial

    def excess(point: tuple[float, np.ndarray, list[Effect]]) -> float:
        """The band's mean log level over the recording's."""
        return float(point[1].mean() - target.mean())

    best: tuple[float, list[Effect]] | None = None
    low, high = math.log(1e-3), math.log(RingDown.PARAM_BOUNDS["amplitude"][1])
    for decay in NEAR_FIELD_DECAYS:
        for rise in NEAR_FIELD_RISES:
            # the band's mean log level against log amplitude is smooth and rising: secant steps from two guesses
            points = [tried(x, decay, rise) for x in (math.log(0.01), math.log(0.1))]
            for _ in range(NEAR_FIELD_SECANT_STEPS):
                (x0, f0), (x1, f1) = [(p[0], excess(p)) for p in points[-2:]]
                x = x1 if f1 == f0 else min(max(x1 - f1 * (x1 - x0) / (f1 - f0), low), high)
                points.append(tried(x, decay, rise))
            _, log_profile, trial = min(points, key=lambda point: abs(excess(point)))
            loss = float(np.abs(log_profile - target).mean())
            if best is None or loss < best[0]:
                best = (loss, trial)
    assert best is not None
    return best[1]


def match_export_knee(calibration: Calibration, chain: Sequence[Effect], real: Fingerprint, real_top: float,
                      n: int, seed: int) -> Calibration:
    """The calibration with the highest export knee at which its simulated frames (texture, gain and export
    included) have the recording's median ratio of the 99.9th percentile to the maximum (`speckle_fit.top_ratio`),
    among the knees that cost the fingerprint nothing: those within KNEE_DISTANCE_SLACK of the best fingerprint
    distance on a ladder down from the knee the texture fit found around the recording's own local means.

    The simulated level reaches full scale over more of the frame than the recording's local mean does (target
    highlights, the residual gain): under the texture fit's knee the calibrated Oculus sim still put 0.05 % of
    its pixels at 255, where the recording has one or two per frame. Matched on the top ratio alone, the knee fell
    to 0.08-0.13 of full scale on both sensors, bending the whole upper range; on the ARIS set that doubled the
    range and bearing profile errors (fingerprint distance 0.24 at knee 1.0, 0.33 at 0.08). Where no allowed
    knee reaches the recording's ratio, the allowed knee with the lowest ratio."""
    assert calibration.texture is not None
    clean = clean_views(calibration, n, seed)  # the knee changes the export only

    def with_knee(knee: float) -> Calibration:
        texture = dataclasses.replace(calibration.texture, export_knee=round(knee, 4))
        return dataclasses.replace(calibration, texture=texture)

    def images_at(knee: float) -> list[np.ndarray]:
        return finished_images(with_knee(knee), clean, chain, seed)

    def top(images: Sequence[np.ndarray]) -> float:
        return float(np.median([top_ratio(i) for i in images]))

    def trial(knee: float) -> tuple[float, float]:
        images = images_at(knee)
        return top(images), distance(fingerprint(images), real)["total"]

    start = calibration.texture.export_knee
    ladder = sorted({*np.arange(start, EXPORT_KNEE_LOW, -KNEE_STEP).tolist(), EXPORT_KNEE_LOW}, reverse=True)
    trials = {knee: trial(knee) for knee in ladder}
    best = min(d for _, d in trials.values())
    allowed = [k for k in ladder if trials[k][1] <= best * (1 + KNEE_DISTANCE_SLACK)]
    reaching = [k for k in allowed if trials[k][0] <= real_top]
    if not reaching:
        return with_knee(min(allowed, key=lambda k: trials[k][0]))
    knee = max(reaching)
    above = ladder[ladder.index(knee) - 1] if knee != ladder[0] else None
    if above in allowed:  # the least compression that does it, between two ladder knees
        low, high = knee, above
        for _ in range(KNEE_REFINE):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if top(images_at(middle)) <= real_top else (low, middle)
        knee = low
    return with_knee(knee)


def _with_noise_floor_interval(fitted: tuple[FittedParameter, ...], calibration: Calibration,
                               chain: Sequence[Effect], images: Sequence[np.ndarray], config: CalibrateConfig,
                               rng: np.random.Generator) -> tuple[FittedParameter, ...]:
    """`fitted` with the noise amplitude's interval from its own fit: the floor matched to the 95th and 5th
    percentiles of the recording's black share over bootstrap resamples of its frames (the effect refits that give
    the other intervals run under the catalogue's speckle, where the amplitude means another floor)."""
    shares = _estimate(np.array([measure.near_zero_fraction(i) for i in images]), np.mean, rng, config.bootstrap)
    # more black pixels wanted: less noise, so the high share gives the low amplitude
    low, high = (effect_in(match_noise_floor(calibration, chain, share, config.mounting_frames, config.seed), TvgNoise)
                 .noise_amplitude for share in (shares.high, shares.low))
    value = effect_in(chain, TvgNoise).noise_amplitude
    interval = Estimate(value, min(low, value), max(high, value))
    return tuple(dataclasses.replace(p, estimate=interval) if (p.effect, p.name) == ("tvg_noise", "noise_amplitude")
                 else p for p in fitted)


def _frames_with_targets(calibration: Calibration, chain: Sequence[Effect], n: int,
                         seed: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Finished calibrated frames (scaled to their maximum) that show a target, with their masks, out of the first
    8 n views of `seed`; the caller stops when it has enough."""
    for index in range(8 * n):
        clean, mask = calibrated_view(calibration, seed, index)
        if mask.any():
            rng = np.random.default_rng([seed, index + 1])
            yield per_frame_rescaled(finish(calibration, clean, chain, rng).intensity), mask


def _sim_highlight(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int) -> float:
    """Median over simulated frames with a target of its return's 95th percentile over the seabed median."""
    ratios = []
    for image, mask in _frames_with_targets(calibration, chain, n, seed):
        seabed = float(np.median(image[measure.seabed_rows(image):]))
        ratios.append(float(np.percentile(image[target_pixels(mask)], 95)) / max(seabed, 1e-6))
        if len(ratios) >= n:
            break
    return float(np.median(ratios)) if ratios else math.nan


def _sim_bins(calibration: Calibration, n: int, seed: int) -> list[float]:
    bins = []
    for index in range(n):
        rng = np.random.default_rng([seed, index, 11])
        modes = calibration.grid.modes
        mode = modes[int(rng.choice(len(modes), p=np.array([m.weight for m in modes]) / sum(m.weight for m in modes)))]
        bins.append((mode.max_range_m - mode.min_range_m) / mode.n_ranges)
    return bins


# ----------------------------------------------------------------------------------------------- effect refit


def with_effects(clean: Sequence[SonarImage], effects: Sequence[Effect], seed: int) -> list[np.ndarray]:
    """The clean frames through `effects`, rescaled per frame like the real export (same seeds every call)."""
    return [per_frame_rescaled(apply_effects(frame, effects, np.random.default_rng([seed, i])).intensity)
            for i, frame in enumerate(clean)]


def effects_from(values: dict[tuple[str, str], float], base: dict[str, Effect] | None = None) -> list[Effect]:
    """The full effect chain with `values` overriding the defaults (or `base`)."""
    chain = dict(base or {name: EFFECTS[name]() for name in PIPELINE_ORDER})
    for (name, param), value in values.items():
        chain[name] = dataclasses.replace(chain[name], **{param: value})
    return [chain[name] for name in PIPELINE_ORDER]


def fit(clean: Sequence[SonarImage], target: Fingerprint, seed: int, rounds: int = 3, log: Any = None,
        start: Sequence[Effect] | None = None, step: float = 0.25) -> tuple[list[Effect], float]:
    """Pattern search over FITTED in coordinates normalised to each PARAM_BOUNDS (log where the class says),
    with common random numbers, from `start` (default: the catalogue defaults); the best chain and its loss."""
    bounds = {(e, p): EFFECTS[e].PARAM_BOUNDS[p] for e, p, _ in FITTED}
    is_log = {(e, p): use_log for e, p, use_log in FITTED}

    def to_unit(key: tuple[str, str], value: float) -> float:
        lo, hi = bounds[key]
        value = min(max(value, lo), hi)
        if is_log[key]:
            return (math.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo))
        return (value - lo) / (hi - lo)

    def from_unit(key: tuple[str, str], u: float) -> float:
        lo, hi = bounds[key]
        u = min(max(u, 0.0), 1.0)
        return math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if is_log[key] else lo + u * (hi - lo)

    base = {e.name: e for e in start} if start else {name: EFFECTS[name]() for name in PIPELINE_ORDER}
    point = {key: to_unit(key, getattr(base[key[0]], key[1])) for key in bounds}

    def loss(p: dict[tuple[str, str], float]) -> float:
        chain = effects_from({k: from_unit(k, u) for k, u in p.items()}, base)
        return distance(fingerprint(with_effects(clean, chain, seed)), target)["total"]

    best = loss(point)
    for round_index in range(rounds):
        for key in bounds:
            trials = []
            for direction in (+1, -1):
                trial = dict(point)
                trial[key] = min(max(point[key] + direction * step, 0.0), 1.0)
                if trial[key] != point[key]:
                    trials.append((loss(trial), trial))
            if trials:
                value, trial = min(trials, key=lambda pair: pair[0])
                if value < best:
                    best, point = value, trial
        if log:
            print(f"calibrate: effects round {round_index + 1}/{rounds}, step {step:.3f}, loss {best:.4f}", file=log)
        step /= 2
    return effects_from({k: _round(from_unit(k, u)) for k, u in point.items()}, base), best


def _round(value: float) -> float:
    """Three significant digits: what gets written."""
    return 0.0 if value == 0 else float(f"{value:.3g}")


def _gain_update(real: Fingerprint, sim: Fingerprint, gamma: float, knots: int, axis: str) -> np.ndarray:
    """Amplitude dB that moves the simulated mean profile onto the real one (output ~ amplitude^gamma)."""
    r, s = (real.row_mean, sim.row_mean) if axis == "range" else (real.column_mean, sim.column_mean)
    ratio_db = 20 * np.log10(np.maximum(r, 1e-3) / np.maximum(s, 1e-3)) / max(gamma, 0.1)
    return np.clip(resample_profile(ratio_db, knots), -12.0, 12.0)


# ----------------------------------------------------------------------------------------------- targets


@dataclass(frozen=True)
class ShadowTarget:
    """A target as `measure.target_shadow` finds it: its shadow's width across (m, at the shadow's start), where
    the shadow starts (over the window's maximum range), the return just ahead of it over the seabed median, and
    the shadow's level over the seabed beside it (`measure.shadow_level`)."""

    width_m: float
    range_fraction: float
    highlight: float
    shadow: float


def shadow_target(frame: SonarImage, image: np.ndarray) -> ShadowTarget | None:
    """The target `measure.target_shadow` finds in `image` (the frame scaled to its maximum), on `frame`'s tables."""
    shadow = measure.target_shadow(image)
    if shadow is None:
        return None
    beam_step = frame.fov_rad / max(frame.n_beams - 1, 1)
    start_m = float(frame.ranges_m[min(shadow.start_row, frame.n_ranges - 1)])
    columns = slice(shadow.first_beam, shadow.first_beam + shadow.width_beams)
    return ShadowTarget(shadow.width_beams * beam_step * start_m, start_m / float(frame.ranges_m[-1]),
                        measure.highlight_ratio(image, columns, shadow.start_row),
                        measure.shadow_level(image, slice(shadow.start_row, shadow.start_row + 1), columns))


def target_terms_from_shadows(frames: Sequence[SonarImage], images: Sequence[np.ndarray], rng: np.random.Generator,
                              resamples: int) -> TargetTerms:
    """Targets where a shadow shows behind a return (one per frame at most), as measured: the share of frames
    with one, the shadow's width across, where it starts, and the return ahead of it. What the detector finds
    is not all there is (it misses targets, and it takes some seabed for one): `match_shadow_targets` then sets
    the share of frames with a simulated target so that the same detector finds them as often in simulation."""
    found = [shadow_target(frame, image) for frame, image in zip(frames, images, strict=True)]
    seen = [t for t in found if t is not None]
    present = np.array([t is not None for t in found], dtype=float)

    def median_of(values: list[float], default: float) -> Estimate:
        return _estimate(np.array(values), np.median, rng, resamples) if values else _fixed(default)

    return TargetTerms(_estimate(present, np.mean, rng, resamples),
                       median_of([t.width_m for t in seen], 0.5), median_of([t.range_fraction for t in seen], 0.5),
                       median_of([t.highlight for t in seen], 2.0), 1.0,
                       shadow_level=_shadow_estimate([t.shadow for t in seen], rng, resamples))


def _shadow_estimate(levels: Sequence[float], rng: np.random.Generator, resamples: int) -> Estimate:
    """The median measured shadow level (0, black shadows, where no target left one to measure)."""
    finite = np.array([v for v in levels if math.isfinite(v)])
    return _estimate(np.clip(finite, 0.0, 2.0), np.median, rng, resamples) if finite.size else _fixed(0.0)


def _shadow_behind(image: np.ndarray, target: AnnotatedObject) -> float:
    """`measure.shadow_level` behind an object (annotated or a mask's), on its bounding box."""
    return measure.shadow_level(image, slice(int(target.rows.min()), int(target.rows.max()) + 1),
                                slice(int(target.cols.min()), int(target.cols.max()) + 1))


def _sim_shadow_level(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int) -> float:
    """Median `measure.shadow_level` behind the simulated targets (their masks' boxes) of up to `n` frames."""
    levels: list[float] = []
    for image, mask in _frames_with_targets(calibration, chain, n, seed):
        levels += [_shadow_behind(image, target) for target in mask_objects(mask)]
        if len(levels) >= n:
            break
    finite = [v for v in levels if math.isfinite(v)]
    return float(np.median(finite)) if finite else math.nan


def match_shadow_floor(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int) -> Calibration:
    """The share of seabed power left in targets' shadows (`targets.shadow_floor`) whose simulated shadows
    measure the recording's `targets.shadow_level`, by bisection (the level rises with the floor). A recording
    whose shadows were not measured keeps black ones.

    The Oculus fit recording's shadows sit at 0.43 of the seabed beside them where the catalogue's effects leave a
    black shadow at 0.22-0.27: the two-sample classifiers tell a black shadow at a glance (docs/RESULTS.md)."""
    t = calibration.targets
    if t.present_fraction.value <= 0 or t.shadow_level.value <= 0:
        return calibration

    def with_floor(floor: float) -> Calibration:
        return dataclasses.replace(calibration, targets=dataclasses.replace(t, shadow_floor=round(floor, 4)))

    low, high = 0.0, 1.0
    for _ in range(SHADOW_FLOOR_STEPS):
        middle = (low + high) / 2
        level = _sim_shadow_level(with_floor(middle), chain, n, seed)
        if not math.isfinite(level):
            return calibration
        low, high = (middle, high) if level < t.shadow_level.value else (low, middle)
    return with_floor((low + high) / 2)


def _sim_shadow_targets(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int,
                        present: float) -> list[ShadowTarget | None]:
    """What the shadow detector finds in `n` simulated frames, targets in a share `present` of them."""
    calibration = dataclasses.replace(calibration, targets=dataclasses.replace(
        calibration.targets, present_fraction=_fixed(present)))
    clean = clean_views(calibration, n, seed)
    return [shadow_target(frame, image) for frame, image in zip(clean, finished_images(calibration, clean, chain, seed),
                                                                strict=True)]


def match_shadow_targets(calibration: Calibration, chain: Sequence[Effect], n: int, seed: int) -> Calibration:
    """Shadow-measured targets set so that the detector finds in simulation what it found in the recording: the
    share of frames with a target whose detection rate is the recording's (the rate is linear in it between the
    rates of frames without and with targets), and the return's gain. Intervals move with their values.

    The size stays the measured shadow width: a target's shadow begins about as wide as the target. A search
    for the size whose simulated shadows measure as wide walked off with the detector's noise (a few detections
    a size; shadows merged with dark seabed beside them), from 1.5 m measured on the Oculus fit recording to
    5.75 m, and from 0.77 m on a synthetic recording of 0.8 m targets to 0.34 m. (The 1.5 m is itself short: the
    fit recording's labels frame an object 6.7 m across at 2 cm bins, whose grey shadow the detector finds only in
    part; `calibrate --targets-from` reads the labels. docs/RESULTS.md, 2026-11-28 19:07.)"""
    t = calibration.targets
    if t.present_fraction.value <= 0:
        return calibration  # nothing found: no targets

    def with_targets(**changes: Any) -> Calibration:
        return dataclasses.replace(calibration, targets=dataclasses.replace(calibration.targets, **changes))

    with_all = _sim_shadow_targets(calibration, chain, n, seed, 1.0)
    rate_all = float(np.mean([f is not None for f in with_all]))
    rate_none = float(np.mean([f is not None for f in _sim_shadow_targets(calibration, chain, n, seed, 0.0)]))
    if rate_all > rate_none + 0.05:
        def share(rate: float) -> float:
            return float(np.clip((rate - rate_none) / (rate_all - rate_none), 0.0, 1.0))
        calibration = with_targets(present_fraction=Estimate(share(t.present_fraction.value),
                                                             share(t.present_fraction.low),
                                                             share(t.present_fraction.high)))
    found = [f.highlight for f in with_all if f is not None and math.isfinite(f.highlight)]
    return _with_highlight_matched(calibration, float(np.median(found)) if found else math.nan)


def match_targets(calibration: Calibration, chain: Sequence[Effect], annotated: bool, config: CalibrateConfig,
                  seed: int) -> Calibration:
    """The measured targets made simulation terms under `chain`: their shadows' floor, then (counted by their
    shadows) the share of frames the detector finds them in and their return, or (from annotations) their
    return alone."""
    calibration = match_shadow_floor(calibration, chain, SHADOW_FLOOR_FRAMES, seed)
    if not annotated:
        return match_shadow_targets(calibration, chain, config.mounting_frames, seed)
    for _ in range(2):
        calibration = _with_highlight_matched(calibration, _sim_highlight(calibration, chain, config.sim_frames, seed))
    return calibration


def _with_highlight_matched(calibration: Calibration, simulated: float) -> Calibration:
    """The targets' return gain moved so that their `simulated` return (over the seabed median, as measured on
    the recording) becomes the recording's `targets.highlight`, through the export's gamma (kept in 0.1..30: the
    simulator's materials are one choice of backscatter, and a recording's targets may return less, as the ARIS
    tank's debris does)."""
    t = calibration.targets
    if not (math.isfinite(simulated) and simulated > 0):
        return calibration
    gamma = float(calibration.effects["gamma_quantization"]["gamma"])
    gain = t.highlight_gain * (t.highlight.value / simulated) ** (1 / gamma)
    return dataclasses.replace(calibration, targets=dataclasses.replace(
        t, highlight_gain=round(float(np.clip(gain, 0.1, 30.0)), 3)))


def target_terms_from_annotations(frames: Sequence[SonarImage], images: Sequence[np.ndarray],
                                  annotations: Annotations, rng: np.random.Generator, resamples: int) -> TargetTerms:
    """Targets as the recording's annotations draw them: the share of frames with any, how many such a frame has,
    and the medians of each object's `annotations.ObjectMeasure`."""
    per_frame = np.array([len(objects) for objects in annotations.objects], dtype=float)
    measured = [m for frame, image, objects in zip(frames, images, annotations.objects, strict=True)
                for m in measure_objects(frame, image, objects)]
    sizes = [m.size_m for m in measured]
    where = [m.range_fraction for m in measured]
    highlights = [m.highlight for m in measured]
    if not sizes:
        raise ConfigError(f"calibrate: {annotations.source} mark no object in any frame (of the classes asked for); "
                          "leave out --targets-from to count targets by their shadows")
    shadows = [_shadow_behind(image, o) for image, objects in zip(images, annotations.objects, strict=True)
               for o in objects]
    return TargetTerms(_estimate((per_frame > 0).astype(float), np.mean, rng, resamples),
                       _estimate(np.clip(sizes, 0.02, 20.0), np.median, rng, resamples),
                       _estimate(np.array(where), np.median, rng, resamples),
                       _estimate(np.array(highlights), np.median, rng, resamples), 1.0,
                       count=_estimate(np.clip(per_frame[per_frame > 0], 1, MAX_TARGETS), np.mean, rng, resamples),
                       source=f"{annotations.source}: {annotations.total} objects in "
                              f"{annotations.frames_with_objects} of {len(frames)} frames",
                       shadow_level=_shadow_estimate(shadows, rng, resamples))


# ----------------------------------------------------------------------------------------------- the whole fit


@remembering_draws()  # its matches evaluate every candidate under the same seeds: each draws the same fields again
def calibrate(frames: Sequence[SonarImage], source: str, config: CalibrateConfig = CalibrateConfig(),
              log: Any = None, annotations: Annotations | None = None) -> CalibrationResult:
    """Everything `sonar-realism calibrate` writes, from the recording alone (and its object annotations, frame by
    frame, when it has them: `annotations.read_annotations`)."""
    config.validate()
    if annotations is not None and len(annotations.objects) != len(frames):
        raise ConfigError(f"calibrate: {len(annotations.objects)} frames of annotations for {len(frames)} frames")
    frames, notes = prepare_frames(frames, config)
    say = (lambda text: print(f"calibrate: {text}", file=log)) if log else (lambda text: None)
    rng = np.random.default_rng(config.seed)
    images = [per_frame_rescaled(f.intensity) for f in frames]
    target = fingerprint(images)
    grid = grid_of(frames)
    say(f"{len(frames)} frames, {len(grid.modes)} grid(s); most common {grid.modes[0]}")

    # mounting from the onset across the fan, per frame
    geometry = [measure.frame_geometry(i, f.ranges_m, f.azimuths_rad, config.vertical_fov_deg)
                for i, f in zip(images, frames, strict=True)]
    seen = np.array([(g.height_m, g.tilt_deg, g.onset_m) for g in geometry if g is not None])
    onset_measured = len(seen) >= max(3, len(frames) // 4)
    if not onset_measured:
        # no water column above the seabed in most frames: the seabed fills the window from its first bin
        seen = np.array([(g.height_m, g.tilt_deg, g.onset_m) for g in (
            measure.filled_window_geometry(f.ranges_m, config.vertical_fov_deg) for f in frames)])
        notes.append(f"only {sum(g is not None for g in geometry)} of {len(frames)} frames "
                     "show a seabed onset below a water column: the seabed fills the window, so the mounting is "
                     "assumed (the aperture's lower edge meets the seabed at the window's start, the beam axis at "
                     "its middle), not measured")
        say(notes[-1])
    b = config.bootstrap
    height = _estimate(seen[:, 0], np.median, rng, b)
    tilt = _estimate(seen[:, 1], np.median, rng, b)
    mounting = Mounting(height, tilt, _estimate(seen[:, 0], _robust_sd, rng, b),
                        _estimate(seen[:, 1], _robust_sd, rng, b), config.vertical_fov_deg)
    real_onsets = _frame_onsets(images, [_bin(f) for f in frames])

    # seabed patchiness and targets, measured on the recording
    real_table = _seabed_table(images, _recording_target_beams(images, annotations))
    real_seabed = _seabed_summary(real_table)
    if math.isfinite(real_seabed.width_beams) and not resolved_width(real_seabed):
        notes.append(f"seabed patches {real_seabed.width_beams:.0f} beams wide, near the measure's "
                     f"{measure.LOCAL_BOX}-beam box: their width is the recording's measure, not matched")
    targets = (target_terms_from_annotations(frames, images, annotations, rng, b) if annotations is not None
               else target_terms_from_shadows(frames, images, rng, b))
    mean_bin = float(np.median([_bin(f) for f in frames]))
    look = SeabedLook(patch_contrast=min(2.5, real_seabed.contrast / 0.6),
                      patch_scale_m=real_seabed.scale_rows * mean_bin,
                      patch_width_deg=float(np.clip(_width_deg(real_seabed, grid), 0.2, 60.0)),
                      dark_fraction=min(0.8, real_seabed.dark_fraction), roughness_m=0.01)
    seabed = look.as_terms()
    defaults = [EFFECTS[name]() for name in PIPELINE_ORDER]
    calibration = Calibration(
        CALIBRATION_VERSION, source, len(frames), grid, mounting, seabed, targets,
        {e.name: e.params() for e in defaults}, (), (0.0,) * GAIN_KNOTS, (0.0,) * GAIN_KNOTS, {},
        export_rescaled=_export_rescaled(frames), notes=tuple(notes))
    n, seed = config.sim_frames, config.seed
    bins = _sim_bins(calibration, n, seed)

    # height: the simulated onset on the real one (same detector), when there is a real one to match
    for _ in range(2 if onset_measured else 0):
        sim_onsets = _frame_onsets(sim_images(calibration, defaults, n, seed, gain=False), bins)
        calibration = match_onsets(calibration, real_onsets, sim_onsets, spread=False)
    mounting = calibration.mounting
    say(f"mounting: height {mounting.height_m.value:.2f} m, tilt {mounting.tilt_deg.value:.1f} deg")
    # seabed look matched under the current effects, then the effects refitted on top; twice, as they interact
    chain = defaults
    look = _match_relief(calibration, chain, look, real_seabed, n, seed)
    for rounds, step in ((config.rounds, 0.25), (1, 0.06)):
        look = _match_seabed(calibration, chain, look, real_seabed, n, seed)
        calibration = dataclasses.replace(calibration, seabed=look.as_terms())
        say(f"seabed: contrast {look.patch_contrast:.2f}, scale {look.patch_scale_m:.2f} m, "
            f"width {look.patch_width_deg:.1f} deg, dark {look.dark_fraction:.2f}, roughness "
            f"{100 * look.roughness_m:.2f} cm")
        clean = clean_views(calibration, n, seed)
        chain, _ = fit(clean, target, seed, rounds, log=log, start=chain, step=step)
        calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
    # the recording's own texture replaces the catalogue's speckle from here on (the effects were fitted with
    # the catalogue's, which the fingerprint search can steer); target highlight and residual gain under it
    if config.texture != "none":
        calibration = dataclasses.replace(calibration, texture=fit_texture(images, config.seed))
        if config.texture == "learned":
            say(f"texture: training the texture generator on the simulated levels against the recording "
                f"({config.learned_steps} steps)")
            calibration = with_learned_texture(calibration, images, config.learned_steps, config.seed,
                                               config.learned_generators)
        # the texture's grain differs from the catalogue speckle's (long along range at dark levels), which
        # changes the measured patchiness: the seabed look matched again under it
        look = _match_seabed(calibration, chain, look, real_seabed, n, seed)
        calibration = dataclasses.replace(calibration, seabed=look.as_terms())
        say(f"texture: the recording's speckle fitted (sim/texture.py); seabed under it: contrast "
            f"{look.patch_contrast:.2f}, scale {look.patch_scale_m:.2f} m, width {look.patch_width_deg:.1f} deg, "
            f"dark {look.dark_fraction:.2f}")
    # the near-field band (ring-down under the receiver's rise) matched on its own profile, before the residual
    # gain: else the gain's first knot lifts whatever the fitted ring-down leaves there (Oculus: +12 dB)
    chain = match_near_field(calibration, chain, near_field_profile(images), config.mounting_frames, seed)
    calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
    ring = effect_in(chain, RingDown)
    say(f"near field: ring-down amplitude {ring.amplitude:.3g}, decay {ring.decay_m:.3g} m, rise {ring.rise_m:.3g} m")
    gamma = float(calibration.effects["gamma_quantization"]["gamma"])
    mounting_bins = _sim_bins(calibration, config.mounting_frames, seed)
    real_top = float(np.median([top_ratio(i) for i in images]))
    for rematch in (True, True, False):  # a last gain update on the settled mounting
        if rematch and onset_measured:
            # the mounting once more under the final chain, texture, export and gain, on more frames: the
            # onset's median and its spread over frames
            sim_onsets = _frame_onsets(sim_images(calibration, chain, config.mounting_frames, seed), mounting_bins)
            calibration = match_onsets(calibration, real_onsets, sim_onsets, spread=True)
        if calibration.texture is not None:
            # under the gain as it stands: the residual gain lifts or lowers the black water as well
            chain = match_noise_floor(calibration, chain, target.near_zero, config.mounting_frames, seed)
            calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
        sim_fp = fingerprint(sim_images(calibration, chain, n, seed))
        range_db = np.clip(np.array(calibration.range_gain_db) + _gain_update(target, sim_fp, gamma, GAIN_KNOTS,
                                                                              "range"), -12, 12)
        bearing_db = np.array(calibration.bearing_gain_db) + _gain_update(target, sim_fp, gamma, GAIN_KNOTS, "bearing")
        bearing_db = np.clip(bearing_db - bearing_db.mean(), -12, 12)
        calibration = dataclasses.replace(calibration, range_gain_db=tuple(round(float(v), 2) for v in range_db),
                                          bearing_gain_db=tuple(round(float(v), 2) for v in bearing_db))
    # the targets on the settled mounting: the detector's shadows depend on where the seabed begins (matched on
    # the first mounting, 0.92 m against the final 0.78 m, the Oculus targets came out 5.75 m wide in every
    # frame, against 1.5 m measured; docs/RESULTS.md)
    calibration = match_targets(calibration, chain, annotations is not None, config, seed)
    say(f"targets: {calibration.targets}")
    if calibration.texture is not None:
        # the top of the range under the final gain and highlights: they set how often the level nears full scale
        calibration = match_export_knee(calibration, chain, target, real_top, config.mounting_frames, seed)
    if config.texture == "learned":
        # the generator once more, on the levels it will be drawn on: the noise floor matched under the first one
        # moved them (Oculus: the floor fell by half), and drawn on levels it was not fitted on its texture is
        # told from the recording's again (held out: texture test 0.97 before this refit, 0.92 after it;
        # docs/RESULTS.md)
        say(f"texture: the texture generator again, on the settled levels ({config.learned_steps} steps)")
        calibration = with_learned_texture(calibration, images, config.learned_steps, config.seed,
                                           config.learned_generators)
        # and the noise floor under it: the new generator draws the dark levels darker or lighter (Oculus: 10.5 %
        # of the pixels black after it, against the recording's 6.1 % matched under the first)
        chain = match_noise_floor(calibration, chain, target.near_zero, config.mounting_frames, seed)
        calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
    # the seabed once more, on the frames as they now come out: every step since its match (near field, noise
    # floor, gains, targets, export knee, the last generator) moves the measured patchiness. The Oculus fit
    # recording's seabed was matched at 0.39 with a patch contrast of 2.31, and its final frames read 0.51; matched
    # again here it lands at 1.59, where the translator trained on it measures better (docs/RESULTS.md)
    look = _match_seabed(calibration, chain, look, real_seabed, n, seed, gain=True)
    calibration = dataclasses.replace(calibration, seabed=look.as_terms())
    say(f"seabed on the final frames: contrast {look.patch_contrast:.2f}, scale {look.patch_scale_m:.2f} m, "
        f"width {look.patch_width_deg:.1f} deg, dark {look.dark_fraction:.2f}")
    if calibration.texture is not None:
        chain = match_noise_floor(calibration, chain, target.near_zero, config.mounting_frames, seed)
        calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
    m = calibration.mounting
    noise = effect_in(chain, TvgNoise).noise_amplitude
    say(f"mounting under the final chain: height {m.height_m.value:.2f} m, heave sd {m.heave_sd_m.value:.3f} m, "
        f"pitch sd {m.pitch_sd_deg.value:.2f} deg; tvg_noise.noise_amplitude {noise:.4f}"
        + (f"; export knee {calibration.texture.export_knee:.3f}" if calibration.texture is not None else ""))

    # intervals of the effect parameters: refits on bootstrap resamples of the recording, each against fresh sim frames
    fitted = _effect_intervals(calibration, chain, images, config, rng, log)
    seabed_intervals = _seabed_intervals(real_table, look, real_seabed, rng, b)
    if calibration.texture is not None:
        fitted = _with_noise_floor_interval(fitted, calibration, chain, images, config, rng)
    calibration = dataclasses.replace(calibration, fitted=fitted, seabed=seabed_intervals)

    # before / after
    uncalibrated = [per_frame_rescaled(f.intensity) for f, _ in simulate("default", "all", n, seed)]
    geometry_only = sim_images(dataclasses.replace(calibration, texture=None), defaults, n, seed, gain=False)
    final = [per_frame_rescaled(f.intensity) for f, _ in simulate_calibrated(calibration, n, seed)]
    fingerprints = {"real": target, "uncalibrated sim": fingerprint(uncalibrated),
                    "geometry + default effects": fingerprint(geometry_only), "calibrated sim": fingerprint(final)}
    distances = {name: round(distance(fp, target)["total"], 4) for name, fp in fingerprints.items() if name != "real"}
    calibration = dataclasses.replace(calibration, distances=distances)
    calibration.validate()
    say(f"fingerprint distance: {distances}")
    examples = {"uncalibrated sim": uncalibrated[:4], "calibrated sim": final[:4]}
    return CalibrationResult(calibration, images, examples, fingerprints)


def with_learned_texture(calibration: Calibration, images: list[np.ndarray], steps: int, seed: int,
                         generators: int, progress: bool = False) -> Calibration:
    """`calibration` with a texture generator trained for `steps` on its own simulated levels (FIT_FRAMES views,
    its effect chain) against the recording `images` (scaled to their maximum), unpaired: the generator learns
    what the simulated scene lacks as well as the sensor's grain. Fitted around the recording's own local
    means instead, it brought the texture test only to 0.97 (docs/RESULTS.md)."""
    levels = texture_levels(calibration, calibration.effect_chain(), FIT_FRAMES, seed)
    return dataclasses.replace(calibration, learned_texture=fit_learned_texture(images, levels, seed, steps,
                                                                                  generators, progress))


def _export_rescaled(frames: Sequence[SonarImage]) -> bool:
    return all(f.intensity.dtype == np.uint8 and int(f.intensity.max()) == 255 for f in frames)


def _effect_intervals(calibration: Calibration, chain: list[Effect], images: list[np.ndarray],
                      config: CalibrateConfig, rng: np.random.Generator, log: Any) -> tuple[FittedParameter, ...]:
    """5-95 % intervals of the effect parameters over refits that each redraw both sources of their spread: a
    bootstrap resample of the recording's frames, and the simulated frames the search compares with it (another
    sim seed). Several parameters trade off in the fingerprint (gamma, the TVG noise and law, sidelobes), so one
    search lands on one of several near-equal fits depending on its seed: a refit on the same simulated frames
    with a small step (before 2026-11-23) gave intervals that did not cover the fit of another `--seed`."""
    values: dict[tuple[str, str], list[float]] = {(e, p): [] for e, p, _ in FITTED}
    n = config.sim_frames
    for draw in range(config.effect_bootstrap):
        resample = [images[i] for i in rng.integers(0, len(images), len(images))]
        sim_seed = int(np.random.SeedSequence([config.seed, 1 + draw]).generate_state(1)[0])
        clean = clean_views(calibration, n, sim_seed)
        refit, _ = fit(clean, fingerprint(resample), sim_seed, rounds=2, start=chain, step=0.25)
        by_name = {e.name: e for e in refit}
        for e, p in values:
            values[(e, p)].append(float(getattr(by_name[e], p)))
    by_name = {e.name: e for e in chain}
    out = []
    for (e, p), draws in values.items():
        value = float(getattr(by_name[e], p))
        low, high = (min(np.percentile(draws, 5), value), max(np.percentile(draws, 95), value)) if draws else (value,
                                                                                                             value)
        out.append(FittedParameter(e, p, Estimate(value, float(low), float(high))))
    if log:
        print(f"calibrate: effect intervals from {config.effect_bootstrap} refits (resampled recording, fresh sim "
              "seed each)", file=log)
    return tuple(out)


def _seabed_intervals(stats: np.ndarray, look: SeabedLook, real: SeabedStats, rng: np.random.Generator,
                      resamples: int) -> SeabedTerms:
    """The matched seabed terms scale with the recording's statistics (`stats`: `_seabed_table`): their intervals
    are the statistics' bootstrap intervals carried through that proportion."""

    columns = [f.name for f in dataclasses.fields(SeabedStats)]  # the table's columns

    def carried(statistic: str, value: float, additive: bool = False) -> Estimate:
        e = _estimate(stats[:, columns.index(statistic)], np.median, rng, resamples)
        reference = getattr(real, statistic)
        if additive:
            return Estimate(value, max(0.0, value + e.low - reference), min(0.9, value + e.high - reference))
        ratio = value / max(reference, 1e-9)
        return Estimate(value, e.low * ratio, e.high * ratio)

    return SeabedTerms(carried("contrast", look.patch_contrast), carried("scale_rows", look.patch_scale_m),
                       carried("width_beams", look.patch_width_deg),
                       carried("dark_fraction", look.dark_fraction, additive=True), _fixed(look.roughness_m))


# ----------------------------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--real", required=True, help="the recording: any file or folder read_frames reads")
    parser.add_argument("--out", required=True, help="the calibration file to write (CALIB.json)")
    parser.add_argument("--report", help="HTML report to write (default: beside --out, .html)")
    parser.add_argument("--match", help="only frames whose source name contains this (e.g. one recording's name)")
    parser.add_argument("--limit", type=positive_int, help="use at most this many frames, evenly spaced")
    parser.add_argument("--vertical-fov", type=float, default=CalibrateConfig.vertical_fov_deg,
                        help="vertical aperture in degrees (not in recordings; default 20, Oculus; ARIS 3000: 14)")
    parser.add_argument("--fov", type=float, default=CalibrateConfig.default_fov_deg,
                        help="bearing span when the recording has no bearing table (default 130)")
    parser.add_argument("--range-bin", type=float, default=CalibrateConfig.default_range_bin_m,
                        help="range bin (m) when the recording has no range window (default 0.02)")
    parser.add_argument("--sim-frames", type=int, default=CalibrateConfig.sim_frames)
    parser.add_argument("--rounds", type=int, default=CalibrateConfig.rounds, help="effect pattern-search rounds")
    parser.add_argument("--effect-bootstrap", type=int, default=CalibrateConfig.effect_bootstrap,
                        help="bootstrap refits for the effect-parameter intervals (default 4; 0: none)")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--texture", choices=TEXTURES, default=CalibrateConfig.texture,
                        help="the simulated texture. learned (default): generators trained on the simulated "
                             "levels against the recording (about 12 minutes, one thread each); speckle: the "
                             "recording's own speckle fitted; none: the catalogue's speckle")
    parser.add_argument("--targets-from", action="append", metavar="FOLDER",
                        help="the recording's object annotations, one file per frame named like it: YOLO box files "
                             "(.txt) or class-id mask images (.png); the targets' share, count, size, range and "
                             "return are then taken from them instead of from shadows (repeat for several folders)")
    parser.add_argument("--target-classes", metavar="IDS",
                        help="with --targets-from: only these class ids are targets, e.g. 1-10 (a wall is not)")
    parser.add_argument("--texture-steps", type=int, default=CalibrateConfig.learned_steps,
                        help=f"training steps of --texture learned (default {DEFAULT_LEARNED_STEPS})")
    parser.add_argument("--texture-generators", type=int, default=CalibrateConfig.learned_generators,
                        help="--texture learned as a mixture of this many generators, fitted side by side, one "
                             f"per core (default {CalibrateConfig.learned_generators})")


def run(args: argparse.Namespace) -> int:
    from sonar_realism.io import load_recording
    from sonar_realism.sim.calibration_report import write_report

    config = CalibrateConfig(vertical_fov_deg=args.vertical_fov, default_fov_deg=args.fov,
                             default_range_bin_m=args.range_bin, sim_frames=args.sim_frames, rounds=args.rounds,
                             effect_bootstrap=args.effect_bootstrap, seed=args.seed, texture=args.texture,
                             learned_steps=args.texture_steps, learned_generators=args.texture_generators)
    config.validate()
    out = output_file(args.out, "--out")
    report = output_file(args.report or out.with_suffix(".html"), "--report")
    frames = load_recording(args.real, args.match, args.limit)
    if args.target_classes and not args.targets_from:
        raise ConfigError("--target-classes needs --targets-from (the folders of the annotations)")
    annotations = (read_annotations(frames, args.targets_from,
                                    parse_classes(args.target_classes) if args.target_classes else None)
                   if args.targets_from else None)
    source = Path(args.real).name + (f" [{args.match}]" if args.match else "")
    result = calibrate(frames, source, config, log=sys.stderr, annotations=annotations)
    save_calibration(result.calibration, out)
    write_report(result, report)
    print(f"wrote {out} and {report}", file=sys.stderr)
    return 0
