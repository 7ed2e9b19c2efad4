"""Blind validation of the diagnosis: "real" frames made from sim frames with effects the diagnosis must find.

The "real" side is made with implementations that differ from the simulator's catalogue (sim.effects): the same
physics by another formula or process, so that a correct identification means the statistics caught the physics,
not that the fit recognised its own code. The hidden parameters are expressed in the catalogue's parameters, so
the fitted values can be compared with them.

| effect             | catalogue (what the diagnosis fits)            | here (what makes the "real" frames)           |
|--------------------|------------------------------------------------|-----------------------------------------------|
| speckle            | Gaussian complex field x gamma texture         | coherent sum of discrete random scatterers    |
|                    |                                                | (Poisson counts, gamma density), sinc PSF     |
| beam_sidelobes     | sinc^2 with rescaled sidelobes, flat floor     | shaded line array with fixed element errors   |
| range_blur         | Gaussian pulse + two Gaussian sidelobes        | compressed pulse: |FT(spectral taper)|^2       |
| tvg_noise          | noise scaled by G(r) added to the signal       | losses, noise at the receiver, then TVG       |
| elevation_spread   | sinc^2 vertical pattern                        | Gaussian vertical pattern                     |
| multipath          | fixed range offset                             | surface image method (offset shrinks with r)  |
| motion_blur        | remap shear + box smear                        | average of time-stepped sub-pings             |
| ring_down          | power sum with per-ping beam ripple            | damped oscillation, fixed ripple, random phase|
| interference       | Poisson arcs at random ranges                  | second sonar: arcs drifting with the ping beat|
| gamma_quantization | round(255 (g A)^gamma)                         | 12-bit ADC with dither, gamma LUT, floor      |

Two effects not in the catalogue are withheld entirely: `beam_gain_ripple` (fixed per-beam gain: vignetting and
a ripple across the fan) and `lens_reflection` (a bright band at a fixed range from a reflection inside the
acoustic lens housing). The diagnosis must leave them as residual, in the right place.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from sonar_realism.diagnose.config import DiagnoseConfig
from sonar_realism.diagnose.diagnosis import diagnose
from sonar_realism.diagnose.result import Diagnosis
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import EFFECTS, PIPELINE_ORDER, SOUND_SPEED_MPS, make_effect, seabed_elevation

AltEffect = Callable[[np.ndarray, SonarImage, dict[str, Any], np.random.Generator], np.ndarray]

# Hidden parameters are drawn from these ranges: inside the catalogue's PARAM_BOUNDS and strong enough to be seen.
# Filled by @alternative: the "real" implementation of each effect and the ranges its hidden parameters are drawn
# from (inside the catalogue's PARAM_BOUNDS and strong enough to be seen). check_catalogue_defaults() holds it to the
# effect registry: every catalogue effect has exactly one alternative.
ALTERNATIVES: dict[str, AltEffect] = {}
HIDDEN_RANGES: dict[str, dict[str, tuple[float, float]]] = {}
# Withheld effects (not in the catalogue) and the catalogue effect each sits before in the physical chain.
WITHHELD_BEFORE: dict[str, str] = {}


def alternative(name: str, hidden: dict[str, tuple[float, float]] | None = None, before: str | None = None,
                ) -> Callable[[AltEffect], AltEffect]:
    """Register `function` as the other implementation of effect `name` (hidden ranges for a catalogue effect,
    `before` for a withheld one)."""
    def register(function: AltEffect) -> AltEffect:
        if name in ALTERNATIVES:
            raise ConfigError(f"validation: two alternative implementations of {name}")
        ALTERNATIVES[name] = function
        if hidden is not None:
            HIDDEN_RANGES[name] = hidden
        if before is not None:
            WITHHELD_BEFORE[name] = before
        return function
    return register


def draw_hidden(name: str, rng: np.random.Generator) -> dict[str, float]:
    """Hidden parameters of a catalogue effect (uniform over HIDDEN_RANGES)."""
    return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in HIDDEN_RANGES[name].items()}


# --- shared physics helpers ----------------------------------------------------------------------------------------

def _taper(points: int, sidelobe_db: float) -> np.ndarray:
    """Aperture (or spectral) weights hann^beta whose pattern's first sidelobe is `sidelobe_db` (-13.3 dB for
    beta = 0, uniform; about -31 dB for beta = 1, Hann)."""
    betas, levels = _sidelobe_table(points)
    beta = float(np.interp(-sidelobe_db, -levels, betas))  # levels fall monotonically with beta
    return _hann_power(points, beta)


@functools.lru_cache(maxsize=8)
def _sidelobe_table(points: int) -> tuple[np.ndarray, np.ndarray]:
    betas = np.linspace(0.0, 2.5, 51)
    return betas, np.array([_first_sidelobe_db(_hann_power(points, b)) for b in betas])


def _hann_power(points: int, beta: float) -> np.ndarray:
    return np.hanning(points + 2)[1:-1] ** beta


def _pattern(weights: np.ndarray, oversample: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Power pattern |FT(weights)|^2 (peak 1) against u in units of 1/aperture, centred on 0."""
    n = len(weights) * oversample
    field = np.fft.fftshift(np.fft.fft(weights, n))
    power = np.abs(field) ** 2
    u = (np.arange(n) - n // 2) / oversample  # cycles across the aperture
    return u, power / power.max()


def _first_sidelobe_db(weights: np.ndarray) -> float:
    u, power = _pattern(weights)
    right = power[u >= 0]
    null = int(np.argmax(np.diff(right) > 0))  # first rise after the mainlobe
    return float(10 * np.log10(max(right[null:].max(), 1e-12)))


def _half_power_width(u: np.ndarray, power: np.ndarray) -> float:
    right = u[(u >= 0) & (power >= 0.5)]
    return 2.0 * float(right.max())


def _sampled_pattern(weights: np.ndarray, half_power_width: float, offsets: np.ndarray) -> np.ndarray:
    """The pattern of `weights`, stretched so its -3 dB width is `half_power_width` (in the units of `offsets`),
    sampled at `offsets`."""
    u, power = _pattern(weights)
    scale = half_power_width / _half_power_width(u, power)
    return np.interp(offsets, u * scale, power, left=0.0, right=0.0)


def _convolve_rows(power: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Every row of `power` convolved with a centred kernel by FFT (zero padded, no wrap)."""
    n = power.shape[-1]
    size = n + len(kernel)
    spectrum = np.fft.rfft(power, size, axis=-1) * np.fft.rfft(kernel, size)
    full = np.fft.irfft(spectrum, size, axis=-1)
    start = len(kernel) // 2
    return np.maximum(full[..., start:start + n], 0.0).astype(np.float32)


# --- alternative implementations of the catalogue ------------------------------------------------------------------

@alternative("speckle", {"shape_nu": (1.0, 20.0), "grain_beams": (0.6, 2.0), "grain_ranges": (0.4, 1.5)})
def alt_speckle(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    per_cell = 4.0
    r, b = x.shape
    density = rng.gamma(p["shape_nu"], 1.0 / p["shape_nu"], size=(r, b))
    counts = rng.poisson(per_cell * density)
    cell = np.repeat(np.arange(counts.size), counts.ravel())
    phase = rng.random(cell.size, dtype=np.float32) * np.float32(2 * math.pi)
    re = np.bincount(cell, np.cos(phase), counts.size).reshape(counts.shape).astype(np.float32)
    im = np.bincount(cell, np.sin(phase), counts.size).reshape(counts.shape).astype(np.float32)
    # sinc amplitude PSF with the -6 dB width of the catalogue's Gaussian cell (FWHM 2.355 sigma; sinc: 1.207 w)
    kb, kr = (_sinc_kernel(2.355 * s / 1.207) for s in (p["grain_beams"], p["grain_ranges"]))
    re = cv2.sepFilter2D(re, -1, kb, kr, borderType=cv2.BORDER_REFLECT_101)
    im = cv2.sepFilter2D(im, -1, kb, kr, borderType=cv2.BORDER_REFLECT_101)
    power = re * re + im * im
    return x * np.sqrt(power / max(float(power.mean()), 1e-12))


def _sinc_kernel(width: float) -> np.ndarray:
    if width < 0.5:
        return np.ones(1, np.float32)
    half = int(math.ceil(4 * width))
    return np.sinc(np.arange(-half, half + 1) / width).astype(np.float32)


@alternative("beam_sidelobes", {"mainlobe_deg": (0.8, 2.5), "sidelobe_db": (-25.0, -13.0),
    "crosstalk_db": (-56.1, -43.1)})
def alt_beam_sidelobes(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    elements = 48
    weights = _taper(elements, p["sidelobe_db"]).astype(np.complex128)
    # A measured pattern: fixed element errors (the instrument's own, not redrawn per ping) raise a ragged floor.
    instrument = np.random.default_rng(12345)
    errors = instrument.standard_normal(elements) + 1j * instrument.standard_normal(elements)
    step = float(np.median(np.diff(np.sin(frame.azimuths_rad))))
    offsets = np.arange(-(frame.n_beams - 1), frame.n_beams) * step
    ideal = _sampled_pattern(weights, math.sin(math.radians(p["mainlobe_deg"])), offsets)
    # leakage into each beam relative to the return (the pattern's total), as the catalogue's crosstalk_db since
    # calibration version 4; the range is the former -35..-22 dB re the row mean at 128 beams (3 dB up at 256)
    floor_target = 10 ** (p["crosstalk_db"] / 10) * ideal.sum()
    noisy = _sampled_pattern(weights + 0.05 * errors, math.sin(math.radians(p["mainlobe_deg"])), offsets)
    far = np.abs(offsets) > 8 * math.sin(math.radians(p["mainlobe_deg"]))
    excess = np.maximum(noisy - ideal, 0.0)
    excess *= floor_target / max(float(excess[far].mean()), 1e-15)
    kernel = ideal + excess
    kernel /= kernel.sum()
    return np.sqrt(_convolve_rows(x * x, kernel))


@alternative("range_blur", {"resolution_m": (0.06, 0.2), "sidelobe_db": (-30.0, -15.0)})
def alt_range_blur(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    # matched-filter output of a pulse with a tapered spectrum: the range PSF is |FT(spectral taper)|^2
    bin_m = frame.range_resolution_m
    offsets = np.arange(-(frame.n_ranges - 1), frame.n_ranges) * bin_m
    kernel = _sampled_pattern(_taper(64, p["sidelobe_db"]), p["resolution_m"], offsets)
    kernel = kernel[np.abs(offsets) <= 6 * p["resolution_m"] + bin_m]
    kernel /= kernel.sum()
    return np.sqrt(_convolve_rows((x * x).T, kernel)).T


@alternative("tvg_noise", {"noise_amplitude": (0.08, 0.3), "tvg_log_coeff_db": (20.0, 40.0),
    "absorption_db_per_m": (0.2, 1.0), "residual_ramp_db": (-6.0, 6.0)})
def alt_tvg_noise(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    r = np.maximum(frame.ranges_m, 1e-3)[:, None]
    loss_db = p["tvg_log_coeff_db"] * np.log10(r) + 2 * p["absorption_db_per_m"] * r
    received = x * 10 ** (-loss_db / 20)
    noise_rms = p["noise_amplitude"] * 10 ** (-loss_db[-1, 0] / 20)  # so that after TVG it is noise_amplitude at r_max
    noise = rng.standard_normal(x.shape) + 1j * rng.standard_normal(x.shape)
    noise = (noise + np.roll(noise, 1, axis=1)) / 2.0  # the beamformer averages neighbouring beams: a 2-beam box
    noise *= noise_rms / math.sqrt(float(np.mean(np.abs(noise) ** 2)))
    span = max(float(r[-1, 0] - r[0, 0]), 1e-9)
    ramp = 10 ** (p.get("residual_ramp_db", 0.0) * (r - r[0, 0]) / span / 20)  # a mis-set TVG affects everything
    return (np.abs(received + noise) * 10 ** (loss_db / 20) * ramp).astype(np.float32)


@alternative("elevation_spread", {"beamwidth_deg": (8.0, 16.0), "floor_db": (-30.0, -15.0)})
def alt_elevation_spread(x: np.ndarray, frame: SonarImage, p: dict[str, Any],
                         rng: np.random.Generator) -> np.ndarray:
    altitude = float(frame.meta.get("sonar_altitude_m", 2.0))
    tilt = float(frame.meta.get("sonar_tilt_rad", math.radians(10.0)))
    phi_deg = np.degrees(seabed_elevation(frame, altitude, tilt))
    weight = np.exp(-4 * math.log(2) * (phi_deg / p["beamwidth_deg"]) ** 2)  # Gaussian beam, -3 dB at +-bw/2
    return (x * np.maximum(weight, 10 ** (p["floor_db"] / 20))).astype(np.float32)


@alternative("multipath", {"reflection_coeff": (0.4, 0.7), "ghost_offset_m": (1.0, 4.0)})
def alt_multipath(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    r = frame.ranges_m
    mid = float(np.median(r))
    offset = p["ghost_offset_m"]
    height = math.sqrt(offset * (mid + offset))  # mirror distance that gives `offset` at mid range
    bin_m = frame.range_resolution_m
    power = (x * x).astype(np.float64)
    out = power.copy()
    source = power.copy()
    for bounce in range(1, int(p.get("n_ghosts", 1)) + 1):
        ghost_r = (r + np.sqrt(r * r + (2 * height * bounce) ** 2)) / 2  # apparent range of the mixed path
        index = (ghost_r - r[0]) / bin_m
        ghost = np.zeros_like(power)
        lower = np.floor(index).astype(int)
        frac = (index - lower)[:, None]
        for shift, weight in ((0, 1 - frac), (1, frac)):
            rows = lower + shift
            keep = rows < len(r)
            np.add.at(ghost, rows[keep], (weight * source)[keep])
        # a rough surface smears the ghost over ~3 bins; the box filter's running sums leave tiny negatives
        # (-1e-17) after a bright row, and on rows with no echo at all (the calibrated scene's empty far range)
        # those made the power negative and its square root NaN
        ghost = np.maximum(cv2.blur(ghost.astype(np.float32), (1, 3)), 0.0)
        out += p["reflection_coeff"] ** (2 * bounce) * ghost
    return np.sqrt(out).astype(np.float32)


@alternative("motion_blur", {"yaw_rate_deg_s": (20.0, 50.0), "surge_m_s": (0.5, 1.5), "integration_s": (0.08, 0.2)})
def alt_motion_blur(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    yaw = math.radians(p["yaw_rate_deg_s"])
    beam_step = float(np.median(np.diff(frame.azimuths_rad)))
    rows, cols = np.indices(x.shape, dtype=np.float32)
    listen = (2 * frame.ranges_m / SOUND_SPEED_MPS)[:, None]
    power = x * x
    total = np.zeros_like(power)
    times = np.linspace(-p["integration_s"] / 2, p["integration_s"] / 2, 9)
    for t in times:  # sub-pings across the integration window, each heard while turning
        map_x = (cols + yaw * (listen + t) / beam_step).astype(np.float32)
        map_y = (rows + p["surge_m_s"] * t / frame.range_resolution_m).astype(np.float32)
        total += cv2.remap(power, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return np.sqrt(np.maximum(total / len(times), 0.0))


@alternative("ring_down", {"amplitude": (0.3, 0.8), "decay_m": (0.1, 0.4), "beam_ripple": (0.1, 0.4)})
def alt_ring_down(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    r = frame.ranges_m - frame.ranges_m[0]
    envelope = p["amplitude"] * np.exp(-r / p["decay_m"]) * (0.8 + 0.2 * np.cos(2 * math.pi * r / (0.4 * p["decay_m"])))
    instrument = np.random.default_rng(777)  # the element-to-element spread is the transducer's own, fixed
    ripple = np.maximum(1.0 + p["beam_ripple"] * instrument.standard_normal(frame.n_beams), 0.0)
    jitter = 1.0 + 0.05 * rng.standard_normal(frame.n_beams)
    ring = envelope[:, None] * (ripple * jitter)[None, :]
    phase = rng.uniform(0, 2 * math.pi, x.shape)
    return np.abs(x + ring * np.exp(1j * phase)).astype(np.float32)


@alternative("water_column", {"haze_level": (0.05, 0.2), "stripe_contrast": (0.2, 0.6),
                              "stripe_width_beams": (1.0, 4.0)})
def alt_water_column(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    """Haze as many weak discrete scatterers per cell (Rayleigh by sum, not by a Gaussian draw); stripes as a
    random walk of per-beam gain in dB, smoothed by a box."""
    per_cell = 6
    phases = rng.uniform(0, 2 * np.pi, (per_cell,) + x.shape)
    haze = np.abs(np.exp(1j * phases).sum(axis=0)) * (p["haze_level"] / math.sqrt(per_cell))
    width = max(1, int(round(2 * p["stripe_width_beams"])))
    steps = rng.standard_normal(x.shape[1] + width)
    gain_db = np.convolve(steps, np.ones(width) / math.sqrt(width), mode="valid")[: x.shape[1]]
    gain = np.exp(p["stripe_contrast"] * gain_db)
    return (np.sqrt(x * x + haze * haze) * gain[None, :]).astype(np.float32)


@alternative("interference", {"rate_per_ping": (1.0, 2.5), "amplitude": (0.4, 0.9), "floor_db": (-20.0, -8.0),
    "thickness_m": (0.03, 0.12)})
def alt_interference(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    r = frame.ranges_m
    span = r[-1] - r[0]
    source = np.random.default_rng(99)  # the other sonar: its bearing and ping-rate beat are fixed
    bearing = source.uniform(frame.azimuths_rad[0], frame.azimuths_rad[-1])
    drift = source.uniform(0.1, 0.3) * span
    across = 10 ** (p["floor_db"] / 10) + np.sinc(np.degrees(frame.azimuths_rad - bearing) / 4.0) ** 2
    out = x * x
    for k in range(int(rng.poisson(p["rate_per_ping"]))):
        at = r[0] + (drift * frame.seq + k * span / 2.7 + rng.uniform(0, 0.05 * span)) % span
        along = (np.abs(r - at) <= p["thickness_m"] / 2).astype(np.float32)  # a rectangular pulse
        if not along.any():
            along[int(np.argmin(np.abs(r - at)))] = 1.0
        out = out + p["amplitude"] ** 2 * along[:, None] * across[None, :]
    return np.sqrt(out).astype(np.float32)


@alternative("gamma_quantization", {"gain": (0.8, 2.0), "gamma": (0.4, 0.7)})
def alt_gamma_quantization(x: np.ndarray, frame: SonarImage, p: dict[str, Any],
                           rng: np.random.Generator) -> np.ndarray:
    adc = np.floor(np.clip(p["gain"] * x, 0.0, 1.0) * 4095 + rng.random(x.shape)) / 4095  # 12-bit ADC, dithered
    return np.clip(np.floor(255 * np.minimum(adc, 1.0) ** p["gamma"] + 0.5), 0, 255).astype(np.uint8)


# --- effects the catalogue does not have ------------------------------------------------------------------------

@alternative("lens_reflection", before="tvg_noise")
def lens_reflection(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    """A bright band at a fixed range (a reflection inside the lens housing) across every beam."""
    r = frame.ranges_m
    centre = r[0] + p.get("at_fraction", 0.62) * (r[-1] - r[0])
    width = p.get("width_fraction", 0.02) * (r[-1] - r[0])
    band = p.get("amplitude", 0.45) * np.exp(-0.5 * ((r - centre) / width) ** 2)
    return np.sqrt(x * x + (band ** 2)[:, None]).astype(np.float32)


@alternative("beam_gain_ripple", before="tvg_noise")
def beam_gain_ripple(x: np.ndarray, frame: SonarImage, p: dict[str, Any], rng: np.random.Generator) -> np.ndarray:
    """Fixed per-beam gain: the fan edges darkened (vignetting) and a ripple across the beams."""
    theta = frame.azimuths_rad
    u = (theta - theta[0]) / max(theta[-1] - theta[0], 1e-9)
    gain = np.cos(theta / 2) ** p.get("vignetting_power", 6.0) * (1 + p.get("ripple", 0.25) *
                                                                   np.sin(2 * math.pi * 5 * u + 0.7))
    return (x * gain[None, :]).astype(np.float32)


WITHHELD: tuple[str, ...] = tuple(WITHHELD_BEFORE)


def _chain_order() -> list[str]:
    """The registry's PIPELINE_ORDER with each withheld effect where it happens physically (lens reflection before
    the receiver, beam gain in it)."""
    order: list[str] = []
    for name in PIPELINE_ORDER:
        order += [w for w, before in WITHHELD_BEFORE.items() if before == name] + [name]
    return order


def make_real(frames: Sequence[SonarImage], hidden: dict[str, dict[str, Any]], seed: int) -> list[SonarImage]:
    """The "real" frames: `frames` with the hidden effects applied by the alternative implementations."""
    unknown = sorted(set(hidden) - set(ALTERNATIVES))
    if unknown:
        raise ConfigError(f"no alternative implementation of {unknown}; have {sorted(ALTERNATIVES)}")
    rng = np.random.default_rng(seed)
    out = []
    for frame in frames:
        planes = frame.normalized()
        planes = planes if planes.ndim == 3 else planes[None]
        results = []
        for plane in planes:
            x = plane.astype(np.float32)
            for name in (n for n in _chain_order() if n in hidden):
                x = ALTERNATIVES[name](x, frame, hidden[name], rng)
            results.append(x)
        stacked = np.stack(results) if frame.intensity.ndim == 3 else results[0]
        if stacked.dtype == np.uint8:
            out.append(frame.replace(intensity=stacked, intensity_scale=255.0, meta={**frame.meta, "source": "blind"}))
        else:
            out.append(frame.replace(intensity=np.clip(stacked, 0.0, None).astype(np.float32), intensity_scale=1.0,
                                     meta={**frame.meta, "source": "blind"}))
    return out


def param_error(fitted: dict[str, Any], truth: dict[str, Any], name: str) -> float:
    """Mean over the hidden continuous parameters of |fitted - true| / width of the catalogue's PARAM_BOUNDS."""
    bounds = EFFECTS[name].PARAM_BOUNDS
    errors = [abs(float(fitted[k]) - float(v)) / (bounds[k][1] - bounds[k][0]) for k, v in truth.items()
              if k in bounds and k in fitted]
    return float(np.mean(errors)) if errors else math.nan


@dataclass(frozen=True)
class BlindResult:
    """One blind case: what was hidden, the diagnosis, and each hidden catalogued effect's parameter error."""

    hidden: dict[str, dict[str, Any]]
    diagnosis: Diagnosis
    param_error: dict[str, float]


def blind_run(sim: Sequence[SonarImage], real_source: Sequence[SonarImage], hidden: dict[str, dict[str, Any]],
              config: DiagnoseConfig, seed: int = 0) -> BlindResult:
    """Diagnose `sim` against `real_source` + hidden effects, without telling the diagnosis what was hidden."""
    real = make_real(real_source, hidden, seed)
    result = diagnose(sim, real, config)
    fitted = result.fitted_params()
    errors = {name: param_error(fitted[name], params, name) for name, params in hidden.items()
              if name in EFFECTS and name in fitted}
    return BlindResult(hidden, result, errors)


def check_catalogue_defaults() -> None:
    """Every catalogue effect has an alternative implementation and hidden ranges inside its bounds."""
    missing = sorted(set(EFFECTS) - set(HIDDEN_RANGES))
    extra = sorted(set(HIDDEN_RANGES) - set(EFFECTS))
    if missing or extra:
        raise ConfigError(f"validation: catalogue effects without an alternative: {missing}; alternatives of effects "
                          f"not in the catalogue: {extra}")
    for name, ranges in HIDDEN_RANGES.items():
        bounds = EFFECTS[name].PARAM_BOUNDS
        for key, (lo, hi) in ranges.items():
            if key not in bounds or lo < bounds[key][0] or hi > bounds[key][1]:
                raise ConfigError(f"validation: hidden range of {name}.{key} {lo}..{hi} outside {bounds.get(key)}")
        make_effect(name)
