"""The fourth validation set: one more form per effect family, written blind after the third had been run
(see heldout/base.py).

Like the third set, this one was written without reading the catalogue's code (`sim/effects.py`) or the diagnosis'
code: only the prose physics and fit bounds of docs/simulator.md and the interface in `heldout/base.py`. Each form
models its family's physics with another model than the catalogue's description and than every earlier set's form.

| family | this set's form | how it differs |
|---|---|---|
| `elevation_spread` | `piston_two_way_roll` | circular piston (jinc^4, real nulls) + floor; roll tilts it by bearing |
| `multipath` | `face_double_bounce` | face <-> target reverberation: ghosts at 2r, 3r (offset grows with range), ~x^k |
| `speckle` | `poisson_scatterers` | Poisson scatterer count per cell (holes); counts per scene, phases per ping |
| `motion_blur` | `sway_translation` | translation (surge + sway) in the window: bearing smear grows towards the sonar |
| `beam_sidelobes` | `near_field_defocus` | unfocused tapered aperture's Fresnel pattern: beams widen at short range |
| `range_blur` | `absorption_broadened_chirp` | Hann-weighted chirp's compressed pulse, widening with range |
| `tvg_noise` | `gain_ceiling_coloured` | TVG gain ceiling (floor plateaus, signal falls); noise coloured in range |
| `interference` | `squinted_chirp_streaks` | a foreign chirp, uncompressed, squinted: slanted radial streaks |
| `ring_down` | `saturated_plateau_broadside` | saturated plateau hiding the echo, then exponential; broadside-peaked |
| `gamma_quantization` | `auto_gain_percentile` | per-ping auto gain (percentile to a fixed level), power law, 8 bits |
| uncatalogued | `tvg_table_ripple` | a fixed periodic gain ripple over one stretch of range, every beam |
| uncatalogued | `fouled_window_sector` | window fouling: loss and angular blur in one bearing sector, all ranges |
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import scipy.fft
from scipy.special import j1

from sonar_realism.diagnose.heldout.base import (
    SECOND_BLIND,
    UNCATALOGUED,
    Param,
    Place,
    ar1,
    bin_m,
    second_blind_form,
    sin_step,
)
from sonar_realism.frames import SonarImage

__all__ = ["SECOND_BLIND"]  # filled by the registrations below

_DEFAULT_ALTITUDE_M = 2.5
_DEFAULT_TILT_RAD = math.radians(15.0)


def _mounting(frame: SonarImage) -> tuple[float, float]:
    """Altitude above the seabed and downward tilt of the beam axis (the simulator's meta; defaults otherwise)."""
    altitude = float(frame.meta.get("sonar_altitude_m", _DEFAULT_ALTITUDE_M) or _DEFAULT_ALTITUDE_M)
    tilt = frame.meta.get("sonar_tilt_rad")
    tilt = _DEFAULT_TILT_RAD if tilt is None else float(tilt)
    return max(altitude, 1e-3), tilt


def _power(x: np.ndarray) -> np.ndarray:
    values = x.astype(np.float32)
    return values * values


def _amplitude(power: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(power, 0.0)).astype(np.float32)


def _modulus(real: np.ndarray, imag: np.ndarray) -> np.ndarray:
    """|real + i imag| in numpy (cv2.magnitude's result depended on the arrays' alignment: not reproducible)."""
    return np.sqrt(real * real + imag * imag)


# --- elevation_spread ------------------------------------------------------------------------------------------------

_JINC_HALF_POWER = 1.6163399  # (2 J1(u) / u)^2 = 1/2


def seabed_elevation(frame: SonarImage, roll_rad: float) -> np.ndarray:
    """Elevation (rad, from the beam axis) at which a flat seabed lies at each pixel, for a sonar at the frame's
    altitude and tilt, rolled by `roll_rad` about its boresight."""
    altitude, tilt = _mounting(frame)
    theta = frame.azimuths_rad[None, :]
    r = np.maximum(frame.ranges_m[:, None], 1e-6)
    # the world height of a ray (bearing theta, elevation phi): sin(phi) b - cos(phi) a, set to -altitude / r
    b = math.cos(roll_rad) * math.cos(tilt)
    a = np.cos(theta) * math.sin(tilt) - np.sin(theta) * math.sin(roll_rad) * math.cos(tilt)
    norm = np.hypot(a, b)
    return np.arctan2(a, b) - np.arcsin(np.clip(altitude / (r * norm), -1.0, 1.0))


def piston_weight(phi: np.ndarray, beamwidth_deg: float, floor_db: float) -> np.ndarray:
    """Amplitude weight of a circular piston's two-way power pattern (jinc^4, one-way -3 dB at +-beamwidth/2) over
    a power floor."""
    u = _JINC_HALF_POWER * np.sin(phi) / math.sin(math.radians(beamwidth_deg) / 2.0)
    safe = np.where(np.abs(u) < 1e-6, 1.0, u)
    jinc = np.where(np.abs(u) < 1e-6, 1.0, 2.0 * j1(safe) / safe)
    floor = 10.0 ** (floor_db / 10.0)
    return np.sqrt(floor + (1.0 - floor) * jinc ** 4)


@second_blind_form("elevation_spread", "piston_two_way_roll", strength="beamwidth_deg",
                   beamwidth_deg=Param(inside=(10.0, 25.0), wide=(4.0, 45.0), catalogue="beamwidth_deg"),
                   floor_db=Param(inside=(-35.0, -15.0), wide=(-50.0, -5.0), catalogue="floor_db"),
                   roll_deg=Param(inside=(-3.0, 3.0), wide=(-10.0, 10.0)))
def piston_two_way_roll(x, frame, p, ping, instrument):
    """Vertical pattern of a circular piston transducer used to send and receive: (2 J1(u)/u)^4 in power, with
    real nulls and -35 dB sidelobes, over a power floor; the seabed's elevation per pixel from the frame's
    altitude and tilt, with a mounting roll that raises the axis on one side of the fan and lowers it on the
    other (the seabed meets the axis at another range on each side). A multiplicative weight; nothing moves."""
    phi = seabed_elevation(frame, math.radians(p["roll_deg"]))
    return (x * piston_weight(phi, p["beamwidth_deg"], p["floor_db"])).astype(np.float32)


# --- multipath -------------------------------------------------------------------------------------------------------

_FACE_ORDERS = (2, 3)


@second_blind_form("multipath", "face_double_bounce", strength="reflection_coeff",
                   reflection_coeff=Param(inside=(0.3, 0.8), wide=(0.1, 0.95), catalogue="reflection_coeff"),
                   flutter=Param(inside=(0.1, 0.4), wide=(0.0, 0.7)))
def face_double_bounce(x, frame, p, ping, instrument):
    """Reverberation between the sonar's face and a target: the echo reflects off the face (a plane of reflection
    coefficient R, whose alignment flutters from ping to ping), goes back to the target and returns, so order k
    appears at k times the target's range, at its bearing, with amplitude R^(k-1) x^k (the target scatters k
    times): strong for bright targets, faint for the seabed; the offset grows with range. Added in power."""
    ranges = frame.ranges_m
    n = ranges.size
    amplitude = np.clip(x.astype(np.float32), 0.0, 1.0)
    reflection = p["reflection_coeff"] * (1.0 - p["flutter"] * float(ping.uniform()))
    ghosts = np.zeros_like(amplitude)
    index = np.arange(n, dtype=np.float64)
    for order in _FACE_ORDERS:
        target = np.interp(order * ranges, ranges, index, right=np.nan)
        source = np.nonzero(np.isfinite(target) & (order * ranges > ranges + 0.5 * bin_m(frame)))[0]
        if source.size == 0:
            continue
        position = target[source]
        low = np.floor(position).astype(np.intp)
        share = (position - low).astype(np.float32)[:, None]
        power = (reflection ** (order - 1) * amplitude[source] ** order) ** 2
        ghosts[low] += (1.0 - share) * power  # k >= 2 bins apart: every low index appears once
        keep = low + 1 < n
        ghosts[low[keep] + 1] += share[keep] * power[keep]
    return _amplitude(_power(x) + ghosts)


# --- speckle ---------------------------------------------------------------------------------------------------------

def grain_kernels(grain_beams: float, grain_ranges: float) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude kernels of the resolution cell: Hann across beams, triangle (a rectangular pulse's response) along
    range, each of half-width grain + 0.5 pixels, scaled so that the filtered field keeps unit power."""
    h_b, h_r = grain_beams + 0.5, grain_ranges + 0.5
    n_b, n_r = np.arange(-math.ceil(h_b), math.ceil(h_b) + 1), np.arange(-math.ceil(h_r), math.ceil(h_r) + 1)
    across = np.where(np.abs(n_b) < h_b, np.cos(np.pi * n_b / (2.0 * h_b)) ** 2, 0.0)
    along = np.clip(1.0 - np.abs(n_r) / h_r, 0.0, None)
    return across / np.sqrt((across ** 2).sum()), along / np.sqrt((along ** 2).sum())


@second_blind_form("speckle", "poisson_scatterers", strength="scatterers_per_cell",
                   scatterers_per_cell=Param(inside=(2.0, 30.0), wide=(0.3, 80.0), catalogue="shape_nu"),
                   grain_beams=Param(inside=(0.8, 3.0), wide=(0.2, 5.0), catalogue="grain_beams"),
                   grain_ranges=Param(inside=(0.5, 2.5), wide=(0.2, 5.0), catalogue="grain_ranges"))
def poisson_scatterers(x, frame, p, ping, instrument):
    """A finite number of scatterers per cell: a Poisson count n of mean N (SI = 1 + 2/N before the cell's
    averaging; a cell with none is a hole) gives each cell a complex Gaussian of power n/N; the field is summed over
    the resolution cell (Hann across beams, triangle along range) and multiplies the amplitude. The counts are the
    scene's (drawn from the frame's speckle_seed when it has one: fixed for a pose), the phases new each ping."""
    shape = x.shape
    seed = frame.meta.get("speckle_seed")
    counts_rng = np.random.default_rng([int(seed), 4099]) if seed is not None else ping
    n_mean = max(p["scatterers_per_cell"], 1e-3)
    texture = np.sqrt(counts_rng.poisson(n_mean, shape) / n_mean).astype(np.float32)
    across, along = grain_kernels(p["grain_beams"], p["grain_ranges"])
    field = ping.standard_normal((2, *shape), dtype=np.float32) * np.float32(math.sqrt(0.5)) * texture
    real = cv2.sepFilter2D(field[0], -1, across.astype(np.float32), along.astype(np.float32),
                           borderType=cv2.BORDER_REFLECT)
    imag = cv2.sepFilter2D(field[1], -1, across.astype(np.float32), along.astype(np.float32),
                           borderType=cv2.BORDER_REFLECT)
    return (x * _modulus(real, imag)).astype(np.float32)


# --- motion_blur -----------------------------------------------------------------------------------------------------

_MAX_LOOKS = 24


@second_blind_form("motion_blur", "sway_translation", strength="integration_s",
                   surge_m_s=Param(inside=(0.2, 1.5), wide=(0.0, 2.5), catalogue="surge_m_s"),
                   sway_m_s=Param(inside=(0.2, 1.0), wide=(0.0, 2.0)),
                   integration_s=Param(inside=(0.08, 0.25), wide=(0.02, 0.5), catalogue="integration_s"))
def sway_translation(x, frame, p, ping, instrument):
    """The vehicle translates (surge forward, sway sideways, each ping its own speeds and sway direction) during
    the integration window: the image is the power mean over the window of the scene seen from each position,
    remapped exactly in Cartesian space. A sideways move sweeps a near echo across many beams and a far one across
    few (angle = displacement / range), a forward move shortens ranges by up to surge x window. No rotation."""
    surge = p["surge_m_s"] * float(ping.uniform(0.5, 1.0))
    sway = p["sway_m_s"] * float(ping.uniform(0.5, 1.0)) * (1.0 if ping.uniform() < 0.5 else -1.0)
    dx, dy = surge * p["integration_s"], sway * p["integration_s"]
    step = bin_m(frame)
    looks = int(np.clip(math.ceil(math.hypot(dx, dy) / step) + 1, 2, _MAX_LOOKS))
    r = frame.ranges_m.astype(np.float32)[:, None]
    cos_t, sin_t = np.cos(frame.azimuths_rad).astype(np.float32), np.sin(frame.azimuths_rad).astype(np.float32)
    forward, lateral = r * cos_t[None, :], r * sin_t[None, :]
    r0, s0, ds = float(frame.ranges_m[0]), float(sin_t[0]), sin_step(frame)
    power = _power(x)
    total = np.zeros_like(power)
    for fraction in np.linspace(-0.5, 0.5, looks):
        xs = forward + np.float32(fraction * dx)
        ys = lateral + np.float32(fraction * dy)
        rs = _modulus(xs, ys)
        rows = (rs - np.float32(r0)) / np.float32(step)
        cols = (ys / np.maximum(rs, np.float32(1e-6)) - np.float32(s0)) / np.float32(ds)
        total += cv2.remap(power, cols, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return _amplitude(total / looks)


# --- beam_sidelobes --------------------------------------------------------------------------------------------------

_APERTURE_SAMPLES = 256
_PATTERN_FFT = 4096
_DEFOCUS_NODES = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.5, 6.5, 9.0, 12.5)  # edge phase error, rad


def _aperture(taper: float) -> np.ndarray:
    xs = (np.arange(_APERTURE_SAMPLES) + 0.5) / _APERTURE_SAMPLES - 0.5
    return xs, 1.0 - taper * (1.0 - np.cos(np.pi * xs) ** 2)


def aperture_pattern(u: np.ndarray, edge_phase: float, taper: float) -> np.ndarray:
    """Power pattern at u (sin-bearing in units of wavelength / aperture) of a line aperture whose amplitude is
    tapered between uniform (taper 0) and Hann (1), seen from a range where the wavefront's curvature leaves a
    quadratic phase of `edge_phase` at its ends (0 in the far field), normalised to 1 at u = 0 in the far field."""
    xs, weights = _aperture(taper)
    field = np.zeros(_PATTERN_FFT, np.complex128)
    field[: xs.size] = weights * np.exp(1j * edge_phase * (2.0 * xs) ** 2)
    spectrum = np.fft.fftshift(np.abs(np.fft.fft(field)) ** 2) / weights.sum() ** 2
    grid_u = (np.arange(_PATTERN_FFT) - _PATTERN_FFT // 2) * (_APERTURE_SAMPLES / _PATTERN_FFT)
    usable = _APERTURE_SAMPLES / 4.0  # beyond it the sampled aperture's images would come in
    return np.where(np.abs(u) <= usable, np.interp(u, grid_u, spectrum), 0.0)


def _half_power_width(taper: float) -> float:
    """Far-field -3 dB full width in u of the tapered aperture."""
    xs, weights = _aperture(taper)

    def level(u: float) -> float:
        return abs((weights * np.exp(-2j * np.pi * u * xs)).sum()) ** 2 / weights.sum() ** 2

    lo, hi = 0.0, 2.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if level(mid) > 0.5 else (lo, mid)
    return 2.0 * lo


def edge_phase_per_row(frame: SonarImage, fresnel_frac: float) -> np.ndarray:
    """Quadratic phase at the aperture's ends, pi/4 * r_F / r, for a near-field distance r_F (= L^2 / lambda)
    that is `fresnel_frac` of the frame's maximum range; capped at the last node."""
    fresnel_m = fresnel_frac * frame.max_range_m
    r = np.maximum(frame.ranges_m, 0.5 * bin_m(frame))
    return np.minimum(0.25 * np.pi * fresnel_m / r, _DEFOCUS_NODES[-1])


def _convolve_rows(values: np.ndarray, kernel: np.ndarray, origin: int) -> np.ndarray:
    """base.fft_convolve along the rows, at a fast FFT length."""
    n = values.shape[1]
    size = scipy.fft.next_fast_len(n + kernel.size, real=True)
    spectrum = scipy.fft.rfft(values, size, axis=1) * scipy.fft.rfft(kernel, size)[None, :]
    return scipy.fft.irfft(spectrum, size, axis=1)[:, origin:origin + n]


@second_blind_form("beam_sidelobes", "near_field_defocus", strength="mainlobe_deg",
                   mainlobe_deg=Param(inside=(0.6, 2.5), wide=(0.3, 4.0), catalogue="mainlobe_deg"),
                   fresnel_frac=Param(inside=(0.1, 0.4), wide=(0.03, 1.2)),
                   taper=Param(inside=(0.3, 0.8), wide=(0.0, 1.0)))
def near_field_defocus(x, frame, p, ping, instrument):
    """An unfocused receive aperture (amplitude taper between uniform and Hann): in its near field the
    wavefront's curvature leaves a quadratic phase across it, pi/4 * r_F/r at its ends, which fills the nulls and
    widens the mainlobe, so the same target smears across more beams the nearer it is. The pattern is computed
    from the aperture (far-field -3 dB width = mainlobe_deg) at a ladder of phase errors and blended per row.
    Power is spread along each constant-range row only."""
    n_beams = x.shape[1]
    width_u = _half_power_width(p["taper"])
    per_beam = sin_step(frame) * width_u / math.radians(p["mainlobe_deg"])  # u between neighbouring beams
    offsets = np.arange(-(n_beams - 1), n_beams) * per_beam
    phase = edge_phase_per_row(frame, p["fresnel_frac"])
    nodes = np.asarray(_DEFOCUS_NODES)
    position = np.interp(phase, nodes, np.arange(nodes.size))
    power = _power(x)
    out = np.zeros_like(power)
    for k, node in enumerate(nodes):
        weight = np.clip(1.0 - np.abs(position - k), 0.0, None)
        rows = np.nonzero(weight > 0.0)[0]
        if rows.size == 0:
            continue
        kernel = aperture_pattern(offsets, float(node), p["taper"])
        kernel /= kernel.sum()
        smeared = _convolve_rows(power[rows], kernel, origin=n_beams - 1)
        out[rows] += (weight[rows, None] * smeared).astype(np.float32)
    return _amplitude(out)


# --- range_blur ------------------------------------------------------------------------------------------------------

def hann_chirp_response(v: np.ndarray) -> np.ndarray:
    """Compressed amplitude of a Hann-weighted chirp at v = bandwidth x delay: sinc(v) / (1 - v^2)."""
    v = np.asarray(v, np.float64)
    near_pole = np.abs(np.abs(v) - 1.0) < 1e-9
    safe = np.where(near_pole, 0.0, v)
    return np.where(near_pole, 0.5, np.sinc(safe) / (1.0 - safe * safe))


def _hann_chirp_half_power() -> float:
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float(hann_chirp_response(np.array(mid))) ** 2 > 0.5 else (lo, mid)
    return 2.0 * lo


_HANN_CHIRP_FWHM = _hann_chirp_half_power()  # ~1.44 in v
_CHIRP_EXTENT = 3.0  # taps out to the second null, v = +-3


def pulse_width_m(frame: SonarImage, p: dict[str, float]) -> np.ndarray:
    """The compressed pulse's -3 dB width (power) per row: resolution_m at the sonar, sqrt(1 + k r) wider at r."""
    return p["resolution_m"] * np.sqrt(1.0 + p["broadening_per_m"] * frame.ranges_m)


def chirp_kernel(width_m: float, step_m: float) -> np.ndarray:
    half = max(1, math.ceil(_CHIRP_EXTENT * width_m / _HANN_CHIRP_FWHM / step_m))
    offsets = np.arange(-half, half + 1) * step_m
    power = hann_chirp_response(offsets * _HANN_CHIRP_FWHM / width_m) ** 2
    return (power / power.sum()).astype(np.float32)


@second_blind_form("range_blur", "absorption_broadened_chirp", strength="resolution_m",
                   resolution_m=Param(inside=(0.04, 0.2), wide=(0.01, 0.4), catalogue="resolution_m"),
                   broadening_per_m=Param(inside=(0.07, 0.3), wide=(0.0, 0.8)))
def absorption_broadened_chirp(x, frame, p, ping, instrument):
    """A Hann-weighted chirp after pulse compression: power response (sinc(v)/(1-v^2))^2, -31 dB sidelobes beyond
    nulls at +-2 and +-3 bandwidth-delays; absorption grows with frequency squared and eats the band's upper part
    with range, so the width grows as sqrt(1 + k r) from resolution_m at the sonar. Kernels at a geometric
    ladder of widths, blended per row (log width). Power stays in its beam."""
    step = bin_m(frame)
    widths = pulse_width_m(frame, p)
    lo, hi = float(widths.min()), float(widths.max())
    count = int(np.clip(math.ceil(math.log(hi / lo) / math.log(1.12)) + 1, 2, 12)) if hi > lo * 1.001 else 1
    ladder = np.geomspace(lo, hi, count) if count > 1 else np.array([lo])
    position = np.interp(np.log(widths), np.log(ladder), np.arange(count)) if count > 1 else np.zeros(widths.size)
    power = _power(x)
    out = np.zeros_like(power)
    for k, width in enumerate(ladder):
        weight = np.clip(1.0 - np.abs(position - k), 0.0, None).astype(np.float32)
        if not weight.any():
            continue
        kernel = chirp_kernel(float(width), step)[:, None]
        smeared = cv2.filter2D(power, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        out += weight[:, None] * smeared
    return _amplitude(out)


# --- tvg_noise -------------------------------------------------------------------------------------------------------

def tvg_gains_db(frame: SonarImage, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(needed, applied) TVG gain per row in dB: spreading n log10 r + two-way absorption 2 alpha r, and the same
    stopped at its ceiling, reached at `ceiling_frac` of the range window."""
    r = np.maximum(frame.ranges_m, 0.5 * bin_m(frame))
    needed = p["tvg_log_coeff_db"] * np.log10(r) + 2.0 * p["absorption_db_per_m"] * r
    r_ceiling = r[0] + p["ceiling_frac"] * (r[-1] - r[0])
    ceiling = p["tvg_log_coeff_db"] * math.log10(r_ceiling) + 2.0 * p["absorption_db_per_m"] * r_ceiling
    return needed, np.minimum(needed, ceiling)


@second_blind_form("tvg_noise", "gain_ceiling_coloured", strength="noise_amplitude",
                   noise_amplitude=Param(inside=(0.05, 0.3), wide=(0.01, 0.6), catalogue="noise_amplitude"),
                   tvg_log_coeff_db=Param(inside=(15.0, 35.0), wide=(5.0, 50.0), catalogue="tvg_log_coeff_db"),
                   absorption_db_per_m=Param(inside=(0.1, 1.5), wide=(0.0, 3.0), catalogue="absorption_db_per_m"),
                   ceiling_frac=Param(inside=(0.5, 0.85), wide=(0.25, 1.0)),
                   noise_corr=Param(inside=(0.3, 0.7), wide=(0.0, 0.9)))
def gain_ceiling_coloured(x, frame, p, ping, instrument):
    """A TVG amplifier with a maximum gain: it follows spreading and absorption (n log10 r + 2 alpha r) up to a
    ceiling, then stays there, so beyond the ceiling's range the signal falls by the gain it lacks and the noise
    floor stops rising (flat, at noise_amplitude, out to the maximum range). The receiver's noise is band-limited:
    complex Gaussian, correlated along range (AR(1), lag-1 noise_corr), independent across beams, new each ping,
    added to the echo's phasor before detection."""
    needed, applied = tvg_gains_db(frame, p)
    signal = x * (10.0 ** ((applied - needed) / 20.0)).astype(np.float32)[:, None]
    rms = (p["noise_amplitude"] * 10.0 ** ((applied - applied[-1]) / 20.0)).astype(np.float32)[:, None]
    white = ping.standard_normal((2, *x.shape), dtype=np.float32)
    coloured = ar1(white, p["noise_corr"], axis=1) * np.float32(math.sqrt(0.5)) * rms
    return _modulus(signal + coloured[0], coloured[1]).astype(np.float32)


# --- interference ----------------------------------------------------------------------------------------------------

def chirp_events(frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                 instrument: np.random.Generator) -> tuple[float, list[tuple[float, float]]]:
    """(sweep direction, [(start range m, source sin-bearing), ...]) of one ping: the foreign sonar's sweep
    direction is the instrument's, the events and their sources new each ping."""
    direction = 1.0 if instrument.uniform() < 0.5 else -1.0
    s = np.sin(frame.azimuths_rad)
    r0, r1 = float(frame.ranges_m[0]), float(frame.ranges_m[-1])
    events = []
    for _ in range(int(ping.poisson(p["rate_per_ping"]))):
        start = float(ping.uniform(r0 - 0.5 * p["streak_m"], r1 - 0.2 * p["streak_m"]))
        source = float(ping.uniform(0.9 * s[0], 0.9 * s[-1]))
        events.append((start, source))
    return direction, events


def streak_centre(source: float, direction: float, sweep_fraction: float, t: np.ndarray) -> np.ndarray:
    """Apparent sin-bearing along a streak (t = 0..1 over its length): the beamformer steers for its own frequency,
    so a foreign frequency f shows the source at sin(theta) f / f0, and the chirp sweeps f."""
    return source * (1.0 + direction * sweep_fraction * (t - 0.5))


@second_blind_form("interference", "squinted_chirp_streaks", strength="amplitude",
                   rate_per_ping=Param(inside=(1.0, 3.0), wide=(0.3, 5.0), catalogue="rate_per_ping"),
                   amplitude=Param(inside=(0.3, 0.9), wide=(0.1, 1.5), catalogue="amplitude"),
                   floor_db=Param(inside=(-35.0, -15.0), wide=(-50.0, -2.0), catalogue="floor_db"),
                   streak_m=Param(inside=(0.5, 2.5), wide=(0.15, 5.0)),
                   sweep_fraction=Param(inside=(0.1, 0.3), wide=(0.03, 0.5)))
def squinted_chirp_streaks(x, frame, p, ping, instrument):
    """Another sonar's FM chirp: the matched filter, made for this sonar's pulse, does not compress it, so each
    arrival lies along range over its whole duration (streak_m), and a phase-steered beamformer squints it: the
    apparent bearing follows the swept frequency, so the streak runs slanted across the fan, near-radial for a
    source at boresight. Across beams: a uniform array's sinc^2 mainlobe about the apparent bearing plus a flat
    sidelobe floor; Tukey ends along range. Poisson count per ping; added in power."""
    direction, events = chirp_events(frame, p, ping, instrument)
    out = _power(x)
    if not events:
        return _amplitude(out)
    ranges = frame.ranges_m
    s = np.sin(frame.azimuths_rad)[None, :]
    beam_rad = float(frame.meta.get("beam_resolution_rad") or 0.0)
    width = math.sin(beam_rad) if beam_rad > 0.0 else 1.5 * sin_step(frame)  # the mainlobe's -3 dB width
    floor = 10.0 ** (p["floor_db"] / 10.0)
    for start, source in events:
        rows = np.nonzero((ranges >= start) & (ranges <= start + p["streak_m"]))[0]
        if rows.size == 0:
            continue
        t = (ranges[rows] - start) / p["streak_m"]
        taper = np.clip(np.minimum(t, 1.0 - t) / 0.1, 0.0, 1.0)
        envelope = np.sin(0.5 * np.pi * taper) ** 2
        centre = streak_centre(source, direction, p["sweep_fraction"], t)[:, None]
        lobe = np.sinc(0.886 * (s - centre) / width) ** 2
        out[rows] += (p["amplitude"] ** 2 * envelope[:, None] * ((1.0 - floor) * lobe + floor)).astype(np.float32)
    return _amplitude(out)


# --- ring_down -------------------------------------------------------------------------------------------------------

_RING_CUT = 1e-4


def ring_extent_m(p: dict[str, float]) -> float:
    """Distance from the first bin beyond which the ring is cut (its envelope below 1e-4)."""
    return p["plateau_m"] + p["decay_m"] * math.log(1.0 / _RING_CUT)


@second_blind_form("ring_down", "saturated_plateau_broadside", strength="amplitude",
                   amplitude=Param(inside=(0.1, 0.6), wide=(0.03, 1.0), catalogue="amplitude"),
                   decay_m=Param(inside=(0.03, 0.2), wide=(0.01, 0.6), catalogue="decay_m"),
                   plateau_m=Param(inside=(0.03, 0.15), wide=(0.0, 0.4)),
                   broadside_width=Param(inside=(0.6, 1.5), wide=(0.3, 3.0)),
                   jitter_db=Param(inside=(0.5, 2.0), wide=(0.0, 4.0)))
def saturated_plateau_broadside(x, frame, p, ping, instrument):
    """Transmit leakage that saturates the receiver: over the first plateau_m the output is the saturation level
    and the echo is lost; then the ring decays exponentially (linear in dB), added in power. The leak reaches the
    beamformer through every element in phase, so it is brightest near broadside: exp(-((sin theta - c)/w)^2),
    the centre c a fixed property of the sensor; its level jitters from ping to ping (log-normal, jitter_db)."""
    centre = float(instrument.uniform(-0.1, 0.1))
    level = p["amplitude"] * 10.0 ** (p["jitter_db"] * float(ping.standard_normal()) / 20.0)
    across = np.exp(-((np.sin(frame.azimuths_rad) - centre) / p["broadside_width"]) ** 2)
    distance = frame.ranges_m - frame.ranges_m[0]
    envelope = np.where(distance <= p["plateau_m"], 1.0,
                        np.exp(-(distance - p["plateau_m"]) / max(p["decay_m"], 1e-6)))
    envelope = np.where(envelope >= _RING_CUT, envelope, 0.0)
    ring = (level * envelope[:, None] * across[None, :]).astype(np.float32)
    out = np.sqrt(_power(x) + ring * ring)
    saturated = distance <= p["plateau_m"]
    out[saturated] = ring[saturated]
    return out.astype(np.float32)


# --- gamma_quantization ----------------------------------------------------------------------------------------------

@second_blind_form("gamma_quantization", "auto_gain_percentile", strength="gamma",
                   gamma=Param(inside=(0.4, 1.0), wide=(0.2, 1.4), catalogue="gamma"),
                   target_level=Param(inside=(0.6, 0.9), wide=(0.3, 1.0)),
                   percentile=Param(inside=(98.0, 99.8), wide=(90.0, 99.95)))
def auto_gain_percentile(x, frame, p, ping, instrument):
    """An automatic gain, set each ping from the ping itself: the amplitude at `percentile` is mapped to
    target_level of full scale through a power law of exponent gamma, rounded to 8 bits and clipped at 255, so the
    output does not depend on the echo's overall level, and only echoes brighter than that percentile by
    target_level^(-1/gamma) saturate."""
    amplitude = np.maximum(x.astype(np.float32), 0.0)
    reference = float(np.percentile(amplitude, p["percentile"]))
    if reference <= 1e-6:
        reference = max(float(amplitude.max()), 1e-6)
    scaled = (amplitude / np.float32(reference)) ** np.float32(p["gamma"]) * np.float32(255.0 * p["target_level"])
    return np.clip(np.floor(scaled + 0.5), 0, 255).astype(np.uint8)


# --- un-catalogued ---------------------------------------------------------------------------------------------------

def _full_fan_deg(frame: SonarImage) -> tuple[float, float]:
    return math.degrees(float(frame.azimuths_rad[0])), math.degrees(float(frame.azimuths_rad[-1]))


def ripple_span_m(frame: SonarImage, p: dict[str, float]) -> tuple[float, float]:
    r0, r1 = float(frame.ranges_m[0]), float(frame.ranges_m[-1])
    start = r0 + p["start_frac"] * (r1 - r0)
    return start, min(r1, start + p["length_frac"] * (r1 - r0))


def _ripple_place(frame: SonarImage, p: dict[str, float]) -> Place:
    return Place(range_m=(ripple_span_m(frame, p),), bearing_deg=(_full_fan_deg(frame),))


@second_blind_form(UNCATALOGUED, "tvg_table_ripple", place=_ripple_place, strength="ripple_db",
                   ripple_db=Param(inside=(1.5, 4.0), wide=(0.5, 8.0)),
                   period_m=Param(inside=(0.2, 0.8), wide=(0.1, 2.0)),
                   start_frac=Param(inside=(0.3, 0.6), wide=(0.1, 0.8)),
                   length_frac=Param(inside=(0.15, 0.3), wide=(0.05, 0.5)))
def tvg_table_ripple(x, frame, p, ping, instrument):
    """A mis-calibrated stretch of the TVG table: over one stretch of range (start_frac, length_frac of the
    window) the gain ripples periodically, ripple_db * sin(2 pi r / period_m + phase), the phase a fixed property
    of the sensor, with short cosine ends; the same gain on every beam and every ping. Nothing else changes."""
    phase = float(instrument.uniform(0.0, 2.0 * math.pi))
    start, end = ripple_span_m(frame, p)
    r = frame.ranges_m
    inside = (r >= start) & (r <= end)
    edge = max(0.1 * (end - start), 1e-9)
    ramp = np.clip(np.minimum(r - start, end - r) / edge, 0.0, 1.0)
    envelope = np.where(inside, np.sin(0.5 * np.pi * ramp) ** 2, 0.0)
    gain_db = p["ripple_db"] * envelope * np.sin(2.0 * np.pi * (r - start) / p["period_m"] + phase)
    out = x.astype(np.float32) * (10.0 ** (gain_db / 20.0)).astype(np.float32)[:, None]
    out[~inside] = x[~inside]
    return out.astype(np.float32)


def fouling_sector_deg(frame: SonarImage, p: dict[str, float]) -> tuple[float, float]:
    lo, hi = _full_fan_deg(frame)
    centre = 0.5 * (lo + hi) + p["centre_frac"] * 0.5 * (hi - lo)
    half = 0.5 * p["width_frac"] * (hi - lo)
    return max(lo, centre - half), min(hi, centre + half)


def _fouling_place(frame: SonarImage, p: dict[str, float]) -> Place:
    return Place(range_m=((float(frame.ranges_m[0]), float(frame.ranges_m[-1])),),
                 bearing_deg=(fouling_sector_deg(frame, p),))


@second_blind_form(UNCATALOGUED, "fouled_window_sector", place=_fouling_place, strength="loss_db",
                   centre_frac=Param(inside=(-0.6, 0.6), wide=(-0.9, 0.9)),
                   width_frac=Param(inside=(0.12, 0.3), wide=(0.05, 0.5)),
                   loss_db=Param(inside=(3.0, 8.0), wide=(1.0, 15.0)),
                   blur_deg=Param(inside=(1.0, 3.0), wide=(0.3, 6.0)))
def fouled_window_sector(x, frame, p, ping, instrument):
    """Biofouling on part of the acoustic window: in one bearing sector (centre and width as fractions of the fan)
    the growth both absorbs (up to loss_db two-way, cos^2 across the sector, patchy by a fixed random profile) and
    scatters the beams, blurring the image across bearing (Gaussian, blur_deg); the same at every range and every
    ping. Outside the sector nothing changes."""
    bearings = np.degrees(frame.azimuths_rad)
    lo, hi = fouling_sector_deg(frame, p)
    centre, width = 0.5 * (lo + hi), max(hi - lo, 1e-9)
    fouled = np.where((bearings > lo) & (bearings < hi), np.cos(np.pi * (bearings - centre) / width) ** 2, 0.0)
    patchy = instrument.standard_normal(bearings.size + 16)
    patchy = np.convolve(patchy, np.hanning(9) / np.hanning(9).sum(), mode="same")[8:-8]
    patchy = np.clip(1.0 + 0.25 * patchy / max(float(patchy.std()), 1e-9), 0.5, 1.5)
    loss = 10.0 ** (-p["loss_db"] * fouled * patchy / 10.0)
    step_deg = float(np.median(np.diff(bearings))) if bearings.size > 1 else 1.0
    sigma = max(p["blur_deg"] / step_deg, 1e-3)
    power = _power(x)
    blurred = cv2.GaussianBlur(power, (0, 1), sigmaX=sigma, sigmaY=1e-6, borderType=cv2.BORDER_REFLECT)
    mixed = ((1.0 - fouled) * power + fouled * blurred) * loss
    out = np.where(fouled[None, :] > 0.0, np.sqrt(np.maximum(mixed, 0.0)), x)
    return out.astype(np.float32)
