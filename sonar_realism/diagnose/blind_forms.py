"""The third validation set: one more form per effect family, written blind (see heldout/base.py).

This set was written without reading the catalogue's code (`sim/effects.py`) or the diagnosis' code: only the
prose physics and fit bounds of docs/simulator.md and the interface in `heldout/base.py`. Each form models the
family's physics with another model, kernel or statistic than the catalogue's description.

| family | this set's form | how it differs from a textbook form |
|---|---|---|
| `elevation_spread` | `gaussian_two_way_beam` | Gaussian vertical pattern (no nulls) + floor; elevation per bearing |
| `multipath` | `surface_bounce_pair` | sea-surface image paths: ghost offset shrinks with range; one-sided tail |
| `speckle` | `rician_lognormal_ar` | Rician speckle times lognormal texture, AR(1) grain, new each ping |
| `motion_blur` | `discrete_look_average` | mean of a few rigid-motion looks (yaw + surge), not a smear |
| `beam_sidelobes` | `hann_array_element_errors` | Hann-tapered array; element errors give a fixed irregular floor |
| `range_blur` | `triangle_rc_tail` | rectangular pulse's triangle response with a causal receiver tail |
| `tvg_noise` | `stepped_gain_multilook` | TVG in discrete steps (staircase); multi-look noise added in power |
| `interference` | `periodic_pulse_comb` | periodic source: comb of rectangular arcs, Cauchy across bearing |
| `ring_down` | `beating_fixed_pattern` | two-mode beating ring; per-beam pattern fixed for the recording |
| `gamma_quantization` | `mu_law_truncate` | mu-law companding, truncating 8-bit ADC |
| uncatalogued | `bracket_arc_shadow` | a bracket's bright arc in a bearing sector, shadow behind it |
| uncatalogued | `beam_board_gain` | adjacent beams on one board with their own flickering gain |
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from sonar_realism.diagnose.heldout.base import (
    BLIND,
    UNCATALOGUED,
    Param,
    Place,
    ar1,
    bin_m,
    blind_form,
    fft_convolve,
    sin_step,
)
from sonar_realism.frames import SonarImage

__all__ = ["BLIND"]  # filled by the registrations below


def _mount(frame: SonarImage) -> tuple[float, float]:
    """Sonar altitude (m) and downward tilt (rad), with fallbacks when the frame does not say."""
    altitude = frame.meta.get("sonar_altitude_m")
    tilt = frame.meta.get("sonar_tilt_rad")
    return (1.5 if altitude is None else float(altitude)), (math.radians(10.0) if tilt is None else float(tilt))


def _amplitude(power: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(power, 0.0)).astype(np.float32)


def _column(frame: SonarImage, bearing_rad: np.ndarray | float) -> np.ndarray:
    """Fractional beam index of a bearing (beams need not be uniformly spaced); -10 outside the fan."""
    return np.interp(bearing_rad, frame.azimuths_rad, np.arange(frame.n_beams), left=-10.0, right=-10.0)


# --- elevation_spread ----------------------------------------------------------------------------------------------

@blind_form("elevation_spread", "gaussian_two_way_beam", strength="beamwidth_deg",
            beamwidth_deg=Param(inside=(10.0, 25.0), wide=(4.0, 60.0), catalogue="beamwidth_deg"),
            floor_db=Param(inside=(-30.0, -12.0), wide=(-50.0, -3.0), catalogue="floor_db"))
def gaussian_two_way_beam(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                          instrument: np.random.Generator) -> np.ndarray:
    """Vertical beam pattern as a Gaussian in elevation (one-way -3 dB at +-beamwidth/2, squared for two ways: no
    nulls, no sidelobe lobes) plus an additive power floor, weighting each pixel by the elevation at which a flat
    seabed lies, solved exactly per range and bearing from the altitude and tilt.

    Multiplicative; peak weight 1 where the seabed is seen on the beam axis; pixels the seabed cannot reach get the
    floor."""
    altitude, tilt = _mount(frame)
    r = np.maximum(frame.ranges_m, 1e-3)[:, None]
    theta = frame.azimuths_rad[None, :]
    # direction (phi elevation, theta bearing) in world z: a*sin(phi) - b*cos(phi) = R*sin(phi - delta) = -h/r
    a, b = math.cos(tilt), np.cos(theta) * math.sin(tilt)
    norm = np.hypot(a, b)
    s = -altitude / (r * norm)
    phi = np.arctan2(b, a) + np.arcsin(np.clip(s, -1.0, 1.0))
    one_way = np.exp(-4.0 * math.log(2.0) * (phi / math.radians(p["beamwidth_deg"])) ** 2)
    floor = 10.0 ** (p["floor_db"] / 10.0)
    weight = np.where(np.abs(s) <= 1.0, (one_way ** 2 + floor) / (1.0 + floor), floor / (1.0 + floor))
    return (x * np.sqrt(weight)).astype(np.float32)


# --- multipath -----------------------------------------------------------------------------------------------------

def _surface_delays(frame: SonarImage, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Extra apparent range of the mixed (one leg via the surface) and double surface paths at each range."""
    r = frame.ranges_m
    bounced = np.sqrt(r ** 2 + 4.0 * height ** 2)  # one way via the sea-surface image (sonar and target at depth H)
    return (bounced - r) / 2.0, bounced - r


@blind_form("multipath", "surface_bounce_pair", strength="reflection_coeff",
            reflection_coeff=Param(inside=(0.3, 0.6), wide=(0.05, 0.95), catalogue="reflection_coeff"),
            surface_height_m=Param(inside=(1.0, 4.0), wide=(0.3, 10.0)),
            tail_m=Param(inside=(0.03, 0.15), wide=(0.005, 0.5)))
def surface_bounce_pair(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                        instrument: np.random.Generator) -> np.ndarray:
    """Sea-surface image paths with sonar and target both `surface_height_m` below the surface: the two mixed paths
    (out direct, back via the surface, and the reverse; power 2R^2) arrive at (r + r_b)/2 and the double bounce
    (R^4) at r_b = sqrt(r^2 + 4H^2), so the ghost offset shrinks with range instead of being a fixed offset.

    The rough surface scatters off-specular energy that can only arrive later: each ghost has a one-sided
    exponential tail along range. Same bearing; power only beyond the direct return."""
    power = x.astype(np.float64) ** 2
    n, step = frame.n_ranges, bin_m(frame)
    rows = np.arange(n)
    coeff = p["reflection_coeff"]
    mapping = np.zeros((n, n))
    for delay, gain in zip(_surface_delays(frame, p["surface_height_m"]), (2.0 * coeff ** 2, coeff ** 4), strict=True):
        target = np.interp(frame.ranges_m + delay, frame.ranges_m, rows, right=np.inf)
        keep = np.isfinite(target)
        low = np.floor(target[keep]).astype(int)
        frac = target[keep] - low
        np.add.at(mapping, (low, rows[keep]), gain * (1.0 - frac))
        inner = low + 1 < n
        np.add.at(mapping, (low[inner] + 1, rows[keep][inner]), gain * frac[inner])
    ghost = mapping @ power
    taps = max(1, int(math.ceil(6.0 * p["tail_m"] / step)))
    kernel = np.exp(-np.arange(taps + 1) * step / max(p["tail_m"], 1e-6))
    ghost = fft_convolve(ghost, kernel / kernel.sum(), axis=0, origin=0)
    return _amplitude(power + np.maximum(ghost, 0.0))


# --- speckle -------------------------------------------------------------------------------------------------------

@blind_form("speckle", "rician_lognormal_ar", strength="diffuse_fraction",
            shape_nu=Param(inside=(2.0, 20.0), wide=(0.3, 200.0), catalogue="shape_nu"),
            grain_beams=Param(inside=(0.8, 2.5), wide=(0.2, 6.0), catalogue="grain_beams"),
            grain_ranges=Param(inside=(0.6, 2.5), wide=(0.2, 6.0), catalogue="grain_ranges"),
            diffuse_fraction=Param(inside=(0.75, 0.95), wide=(0.0, 1.0)))
def rician_lognormal_ar(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                        instrument: np.random.Generator) -> np.ndarray:
    """Rician speckle (a coherent component plus a diffuse circular Gaussian part holding `diffuse_fraction` of the
    power) times a lognormal texture of variance 1/shape_nu (a Suzuki-like law, not K), with separable AR(1)
    (exponential) grain correlation instead of a low-pass resolution cell, redrawn every ping.

    Multiplicative and mean-power preserving; the texture is correlated over three times the speckle grain."""
    shape = x.shape
    diffuse = ping.standard_normal(shape) + 1j * ping.standard_normal(shape)
    diffuse = ar1(ar1(diffuse / math.sqrt(2.0), math.exp(-1.0 / p["grain_ranges"]), 0),
                  math.exp(-1.0 / p["grain_beams"]), 1)
    d = p["diffuse_fraction"]
    speckle = np.abs(math.sqrt(1.0 - d) + math.sqrt(d) * diffuse) ** 2
    sigma = math.sqrt(math.log1p(1.0 / p["shape_nu"]))
    field = ar1(ar1(ping.standard_normal(shape), math.exp(-1.0 / (3.0 * p["grain_ranges"])), 0),
                math.exp(-1.0 / (3.0 * p["grain_beams"])), 1)
    texture = np.exp(sigma * field - 0.5 * sigma ** 2)
    return (x * np.sqrt(speckle * texture)).astype(np.float32)


# --- motion_blur ---------------------------------------------------------------------------------------------------

@blind_form("motion_blur", "discrete_look_average", strength="window_s",
            yaw_rate_deg_s=Param(inside=(15.0, 45.0), wide=(0.0, 90.0), catalogue="yaw_rate_deg_s"),
            surge_m_s=Param(inside=(0.3, 1.2), wide=(0.0, 3.0), catalogue="surge_m_s"),
            window_s=Param(inside=(0.08, 0.25), wide=(0.01, 0.6), catalogue="integration_s"),
            n_looks=Param(inside=(3.0, 5.0), wide=(2.0, 8.0), integer=True))
def discrete_look_average(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                          instrument: np.random.Generator) -> np.ndarray:
    """The frame as the incoherent mean of `n_looks` discrete looks spread over `window_s` (ping averaging), each the
    scene moved rigidly by the platform's yaw and surge at that instant: a forward surge shortens range by v*t*cos
    (bearing) and shifts bearing too, and a fast yaw leaves separate ghost copies rather than a continuous smear.

    No within-ping shear; power is averaged over the looks."""
    power = (x.astype(np.float32) ** 2)
    rows_of = np.arange(frame.n_ranges)
    r, theta = np.meshgrid(frame.ranges_m, frame.azimuths_rad, indexing="ij")
    out = np.zeros_like(power)
    looks = max(1, int(p["n_looks"]))
    for t in np.linspace(-0.5, 0.5, looks) * p["window_s"]:
        turned = theta + math.radians(p["yaw_rate_deg_s"]) * t
        fwd = r * np.cos(turned) + p["surge_m_s"] * t
        side = r * np.sin(turned)
        src_rows = np.interp(np.hypot(fwd, side), frame.ranges_m, rows_of, left=-10.0, right=-10.0)
        src_cols = _column(frame, np.arctan2(side, fwd))
        out += cv2.remap(power, src_cols.astype(np.float32), src_rows.astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return _amplitude(out / looks)


# --- beam_sidelobes ------------------------------------------------------------------------------------------------

def _array_pattern(frame: SonarImage, p: dict[str, float], instrument: np.random.Generator) -> np.ndarray:
    """Receive power pattern of a half-wavelength Hann-tapered line array with random complex element errors, at
    the beam offsets k*sin_step (k = -(n-1)..n-1), normalised to unit sum."""
    n = frame.n_beams
    u = np.arange(-(n - 1), n) * sin_step(frame)
    elements = max(8, int(round(2.88 / math.radians(p["mainlobe_deg"]))))  # Hann: -3 dB width 1.44 lambda/L
    taper = np.hanning(elements + 2)[1:-1]
    ratio = float((taper ** 2).sum() / taper.sum() ** 2)  # mean error-sidelobe power per unit error variance
    variance = 10.0 ** (p["error_floor_db"] / 10.0) / ratio
    errors = math.sqrt(variance / 2.0) * (instrument.standard_normal(elements)
                                          + 1j * instrument.standard_normal(elements))
    index = np.arange(elements) - (elements - 1) / 2.0
    factor = np.exp(1j * math.pi * np.outer(u, index)) @ (taper * (1.0 + errors))
    pattern = np.abs(factor) ** 2
    return pattern / pattern.sum()


@blind_form("beam_sidelobes", "hann_array_element_errors", strength="error_floor_db",
            mainlobe_deg=Param(inside=(0.8, 2.0), wide=(0.3, 4.0), catalogue="mainlobe_deg"),
            error_floor_db=Param(inside=(-32.0, -18.0), wide=(-55.0, -6.0), catalogue="sidelobe_db"))
def hann_array_element_errors(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                              instrument: np.random.Generator) -> np.ndarray:
    """Beam pattern computed from a Hann-tapered half-wavelength line array (smooth mainlobe, low taper sidelobes)
    whose random complex element errors, fixed for the instrument, raise an irregular, non-flat sidelobe floor of
    mean level `error_floor_db`; one kernel in sin(bearing), applied in power along each row.

    Unit-sum kernel: an extended uniform scene keeps its level, a point spreads along its constant-range arc."""
    kernel = _array_pattern(frame, p, instrument)
    power = fft_convolve(x.astype(np.float64) ** 2, kernel, axis=1, origin=frame.n_beams - 1)
    return _amplitude(power)


# --- range_blur ----------------------------------------------------------------------------------------------------

def _pulse_kernel(frame: SonarImage, p: dict[str, float]) -> tuple[np.ndarray, int]:
    step = bin_m(frame)
    res = p["resolution_m"]
    half = max(1, int(math.ceil(res / step)))
    triangle = np.clip(1.0 - np.abs(np.arange(-half, half + 1) * step) / res, 0.0, None)
    triangle[half] = max(triangle[half], 1e-12)
    tail = np.array([1.0])
    if p["tail_m"] > 1e-6:
        tail = np.exp(-np.arange(int(math.ceil(6.0 * p["tail_m"] / step)) + 1) * step / p["tail_m"])
    kernel = np.convolve(triangle, tail)
    return kernel / kernel.sum(), half


@blind_form("range_blur", "triangle_rc_tail", strength="resolution_m",
            resolution_m=Param(inside=(0.05, 0.15), wide=(0.01, 0.4), catalogue="resolution_m"),
            tail_m=Param(inside=(0.02, 0.08), wide=(0.0, 0.3)))
def triangle_rc_tail(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                     instrument: np.random.Generator) -> np.ndarray:
    """Range response of a rectangular CW pulse through a matched filter (a triangle, FWHM = resolution, no range
    sidelobes) followed by a band-limited receiver's causal exponential tail (RC recovery), so the smear is
    asymmetric: energy only trails towards longer range beyond the triangle.

    Applied in power along each beam with a unit-sum kernel; beams never mix."""
    kernel, origin = _pulse_kernel(frame, p)
    return _amplitude(fft_convolve(x.astype(np.float64) ** 2, kernel, axis=0, origin=origin))


# --- tvg_noise -----------------------------------------------------------------------------------------------------

def _stepped_gain_db(frame: SonarImage, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Ideal TVG (n log10 r + 2 alpha r, dB) and the stepped gain the receiver applies (nearest multiple of step)."""
    r = np.maximum(frame.ranges_m, bin_m(frame))
    ideal = p["tvg_log_coeff_db"] * np.log10(r) + 2.0 * p["absorption_db_per_m"] * r
    return ideal, p["step_db"] * np.round(ideal / p["step_db"])


@blind_form("tvg_noise", "stepped_gain_multilook", strength="noise_amplitude",
            noise_amplitude=Param(inside=(0.08, 0.25), wide=(0.01, 0.6), catalogue="noise_amplitude"),
            tvg_log_coeff_db=Param(inside=(15.0, 35.0), wide=(5.0, 50.0), catalogue="tvg_log_coeff_db"),
            absorption_db_per_m=Param(inside=(0.2, 1.0), wide=(0.0, 2.5), catalogue="absorption_db_per_m"),
            step_db=Param(inside=(3.0, 8.0), wide=(0.5, 12.0)),
            looks=Param(inside=(2.0, 4.0), wide=(1.0, 8.0), integer=True))
def stepped_gain_multilook(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                           instrument: np.random.Generator) -> np.ndarray:
    """A TVG switched in discrete gain steps: the signal keeps a sawtooth residual of +-step/2 dB about the ideal
    spreading-and-absorption law, and pre-TVG electronic noise comes out as a staircase floor (rms
    `noise_amplitude` at the maximum range).

    The noise power is averaged over `looks` envelopes and a two-sample pulse (gamma-distributed, not Rayleigh),
    correlated along range, white across beams, and added in power rather than as a phasor; new every ping."""
    ideal, actual = _stepped_gain_db(frame, p)
    residual = 10.0 ** ((actual - ideal) / 20.0)
    rms = p["noise_amplitude"] * 10.0 ** ((actual - actual[-1]) / 20.0)
    looks = max(1, int(p["looks"]))
    n_r, n_b = x.shape
    looked = ping.gamma(looks, 1.0 / looks, (n_r + 1, n_b))  # noise power averaged over `looks` envelopes
    noise = (looked[1:] + looked[:-1]) / 2.0  # and over a two-sample pulse: lag-1 correlation 0.5, mean 1
    return _amplitude((x * residual[:, None]) ** 2 + (rms ** 2)[:, None] * noise)


# --- interference --------------------------------------------------------------------------------------------------

@blind_form("interference", "periodic_pulse_comb", strength="amplitude",
            amplitude=Param(inside=(0.3, 0.8), wide=(0.03, 1.5), catalogue="amplitude"),
            thickness_m=Param(inside=(0.02, 0.15), wide=(0.005, 0.4), catalogue="thickness_m"),
            repeat_m=Param(inside=(2.0, 5.0), wide=(0.5, 15.0)),
            spread_deg=Param(inside=(3.0, 12.0), wide=(0.5, 40.0)))
def periodic_pulse_comb(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                        instrument: np.random.Generator) -> np.ndarray:
    """An unsynchronised periodic source (a DVL or another sonar pinging faster than us): within one ping its
    pulses arrive at a regular apparent-range spacing `repeat_m` whose phase drifts randomly from ping to ping, from
    one fixed bearing (per recording).

    Each pulse is a rectangular envelope `thickness_m` long (unmatched CW), with a Cauchy (Lorentzian) profile in
    sin(bearing) across the fan instead of a mainlobe plus flat floor; added in power."""
    r, step = frame.ranges_m, bin_m(frame)
    repeat, thick = p["repeat_m"], p["thickness_m"]
    source = instrument.uniform(-0.8, 0.8) * max(abs(frame.azimuths_rad[0]), abs(frame.azimuths_rad[-1]))
    centres = r[0] + ping.uniform(0.0, repeat) + repeat * np.arange(int((r[-1] - r[0]) / repeat) + 2)
    low = np.maximum(r[:, None] - step / 2.0, centres[None, :] - thick / 2.0)
    high = np.minimum(r[:, None] + step / 2.0, centres[None, :] + thick / 2.0)
    fill = np.minimum(np.clip(high - low, 0.0, None).sum(axis=1) / step, 1.0)
    du = (np.sin(frame.azimuths_rad) - math.sin(source)) / math.sin(math.radians(p["spread_deg"]))
    added = p["amplitude"] ** 2 * fill[:, None] / (1.0 + du[None, :] ** 2)
    return _amplitude(x.astype(np.float64) ** 2 + added)


# --- ring_down -----------------------------------------------------------------------------------------------------

def _ring_extent_m(p: dict[str, float]) -> float:
    """Distance past the first bin beyond which the ring is cut (its envelope below 1e-4 of its start)."""
    return p["decay_m"] * math.log(1e4)


@blind_form("ring_down", "beating_fixed_pattern", strength="amplitude",
            amplitude=Param(inside=(0.3, 0.8), wide=(0.02, 1.5), catalogue="amplitude"),
            decay_m=Param(inside=(0.03, 0.15), wide=(0.005, 0.6), catalogue="decay_m"),
            beam_ripple=Param(inside=(0.2, 0.6), wide=(0.0, 1.2), catalogue="beam_ripple"),
            beat_m=Param(inside=(0.03, 0.1), wide=(0.01, 0.4)),
            beat_depth=Param(inside=(0.3, 0.8), wide=(0.0, 1.0)))
def beating_fixed_pattern(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                          instrument: np.random.Generator) -> np.ndarray:
    """Transmit leakage ringing as two close transducer modes: an exponential envelope modulated by their beat
    |1 + m e^(i 2 pi d / beat)| / (1 + m), so the band shows fringes along range, and a smooth per-beam coupling
    pattern fixed by the hardware (drawn once per recording), not redrawn each ping.

    Added in power; cut to zero once the envelope falls below 1e-4 of its start."""
    d = frame.ranges_m - frame.ranges_m[0]
    m = p["beat_depth"]
    envelope = p["amplitude"] * np.exp(-d / p["decay_m"]) * np.abs(1.0 + m * np.exp(2j * math.pi * d / p["beat_m"]))
    envelope = np.where(d <= _ring_extent_m(p), envelope / (1.0 + m), 0.0)
    coupling = ar1(instrument.standard_normal(frame.n_beams), math.exp(-1.0 / 8.0), 0)
    pattern = np.clip(1.0 + p["beam_ripple"] * coupling, 0.0, None)
    return _amplitude(x.astype(np.float64) ** 2 + (envelope[:, None] * pattern[None, :]) ** 2)


# --- gamma_quantization --------------------------------------------------------------------------------------------

@blind_form("gamma_quantization", "mu_law_truncate", strength="mu",
            gain=Param(inside=(0.6, 2.0), wide=(0.1, 8.0), catalogue="gain"),
            mu=Param(inside=(20.0, 255.0), wide=(0.5, 5000.0)))
def mu_law_truncate(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                    instrument: np.random.Generator) -> np.ndarray:
    """Output mapping by mu-law companding, v = 255 ln(1 + mu g A) / ln(1 + mu), instead of a power law: nearly
    linear at small mu, logarithmic at large mu; then a truncating 8-bit ADC (floor, not round), saturating at 255.
    """
    level = np.log1p(p["mu"] * np.clip(p["gain"] * x.astype(np.float64), 0.0, None)) / math.log1p(p["mu"])
    return np.clip(np.floor(255.0 * level), 0, 255).astype(np.uint8)


# --- uncatalogued: a mounting bracket in the fan -------------------------------------------------------------------

def _bracket_place(frame: SonarImage, p: dict[str, float]) -> Place:
    half = p["sector_width_deg"] / 2.0
    start = p["arc_range_m"] - 3.0 * p["arc_thickness_m"]
    return Place(range_m=((start, max(frame.max_range_m, start)),),
                 bearing_deg=((p["sector_center_deg"] - half, p["sector_center_deg"] + half),))


@blind_form(UNCATALOGUED, "bracket_arc_shadow", place=_bracket_place, strength="brightness",
            arc_range_m=Param(inside=(1.0, 3.0), wide=(0.6, 5.0)),
            arc_thickness_m=Param(inside=(0.02, 0.06), wide=(0.01, 0.15)),
            sector_center_deg=Param(inside=(-40.0, 40.0), wide=(-55.0, 55.0)),
            sector_width_deg=Param(inside=(8.0, 20.0), wide=(2.0, 45.0)),
            brightness=Param(inside=(0.4, 0.9), wide=(0.03, 1.2)),
            shadow_db=Param(inside=(-12.0, -4.0), wide=(-30.0, 0.0)))
def bracket_arc_shadow(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                       instrument: np.random.Generator) -> np.ndarray:
    """A mounting bracket (or a housing edge) inside the fan: a fixed bright constant-range arc at `arc_range_m`
    across a bearing sector, and an acoustic shadow of `shadow_db` behind it in that sector, the same every ping.

    The sector has 1-degree soft edges inside its nominal bounds; the arc is Gaussian in range, cut at 3 sigma."""
    bearing = np.degrees(frame.azimuths_rad)
    offset = np.abs(bearing - p["sector_center_deg"])
    sector = np.clip(p["sector_width_deg"] / 2.0 - offset, 0.0, 1.0)[None, :]
    dr = (frame.ranges_m - p["arc_range_m"])[:, None]
    sigma = p["arc_thickness_m"]
    arc = np.where(np.abs(dr) <= 3.0 * sigma, p["brightness"] * np.exp(-0.5 * (dr / sigma) ** 2), 0.0)
    shadow = 1.0 - (1.0 - 10.0 ** (p["shadow_db"] / 20.0)) * (dr > 0) * sector
    return _amplitude((x * shadow) ** 2 + (arc * sector) ** 2)


# --- uncatalogued: one beam group with its own gain ----------------------------------------------------------------

def _board_columns(frame: SonarImage, p: dict[str, float]) -> tuple[int, int]:
    count = int(min(max(1, p["board_beams"]), frame.n_beams))
    centre = int(np.argmin(np.abs(np.degrees(frame.azimuths_rad) - p["centre_deg"])))
    start = int(np.clip(centre - count // 2, 0, frame.n_beams - count))
    return start, start + count


def _board_place(frame: SonarImage, p: dict[str, float]) -> Place:
    start, stop = _board_columns(frame, p)
    bearing = np.degrees(frame.azimuths_rad)
    return Place(range_m=((float(frame.ranges_m[0]), frame.max_range_m),),
                 bearing_deg=((float(bearing[start]), float(bearing[stop - 1])),))


@blind_form(UNCATALOGUED, "beam_board_gain", place=_board_place, strength="gain_db",
            centre_deg=Param(inside=(-40.0, 40.0), wide=(-60.0, 60.0)),
            board_beams=Param(inside=(16.0, 32.0), wide=(4.0, 64.0), integer=True),
            gain_db=Param(inside=(-8.0, -3.0), wide=(-14.0, -0.5)),
            flicker_db=Param(inside=(0.5, 1.5), wide=(0.0, 3.0)))
def beam_board_gain(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                    instrument: np.random.Generator) -> np.ndarray:
    """One contiguous group of beams formed on its own processing board (an FPGA lane or receiver card) with its own
    gain: a sharp-edged bearing sector offset by `gain_db` that also flickers by `flicker_db` rms from ping to ping.

    Multiplicative, at every range of those beams; the other beams are untouched."""
    start, stop = _board_columns(frame, p)
    gain_db = p["gain_db"] + p["flicker_db"] * ping.standard_normal()
    y = x.astype(np.float32, copy=True)
    y[:, start:stop] *= np.float32(10.0 ** (gain_db / 20.0))
    return y
