"""The catalogue of real-sensor effects: each one a switchable, parametrised stage on a polar image.

Every effect is a frozen dataclass whose fields are its physical parameters (Oculus M1200d-class defaults),
with `validate()` (raises ConfigError), a class attribute `PARAM_BOUNDS` (the plausible search range of each
continuous parameter, for fitting) and `apply(intensity, frame, rng)`:

- `intensity` is float32 linear amplitude `[..., n_ranges, n_beams]` (a clean simulation lies in ~[0, 1]);
  a leading sample axis is carried through untouched;
- `frame` supplies the geometry (ranges_m, azimuths_rad) and meta (sonar altitude/tilt, speckle seed);
- `rng` is the only source of random draws, so a seed reproduces a frame exactly.

Effects act on amplitude A, but physical mixing (beam pattern, pulse, multipath) adds powers, so those
stages work on I = A^2 and return sqrt(I). `apply_effects` runs a chosen set in the canonical physical order
`PIPELINE_ORDER`; `gamma_quantization` is last and turns the result into 8-bit counts.

Defaults marked "calibrated" were fitted to the real Oculus set (389 frames) by
`python -m sonar_realism.sim.calibrate --real "$SONAR_REALISM_DATA"/real/oculus_polar_seabed/dataset --out docs/img`
(8 default-scene frames, seed 0, 6 pattern-search rounds; see docs/simulator.md); the others are sensor-sheet
or textbook values that the fit left where they were.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import cv2
import numpy as np

from sonar_realism.config import from_dict, to_dict
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim.repeated_draws import remembered_draw

SOUND_SPEED_MPS = 1500.0
# Used when a frame does not say how the sonar sits over the seabed (simulated frames always do).
DEFAULT_ALTITUDE_M = 2.0
DEFAULT_TILT_RAD = math.radians(10.0)


# The catalogue: every Effect subclass declared with `order=` registers itself here (name -> class).
_REGISTRY: dict[str, type[Effect]] = {}


class Effect(abc.ABC):
    """Base of every effect stage. Subclasses are frozen dataclasses of physical parameters.

    A subclass joins the catalogue by naming its place in the forward model: `class X(Effect, order=55)`.
    Everything that lists effects (EFFECTS, PIPELINE_ORDER, the calibration's fitted parameters, the
    diagnosis' validation) derives from that registry, so adding an effect is adding one class.
    """

    name: ClassVar[str]
    # Position in the physical forward model (PIPELINE_ORDER sorts by it).
    ORDER: ClassVar[float]
    # Plausible range of each continuous parameter (what a fit searches over), in the order the diagnosis' coordinate
    # search sweeps them (it matters where a parameter at its bound switches the effect off: see RingDown).
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]]
    # Hard physical limits (inclusive) that validate() enforces; wider than PARAM_BOUNDS.
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]]
    # Parameters searched on a log scale (they span decades).
    LOG_SCALE: ClassVar[frozenset[str]] = frozenset()
    # Parameters the calibration refits to a real recording; the others keep their physical defaults.
    CALIBRATED: ClassVar[tuple[str, ...]] = ()
    # Parameters that carry what the effect adds beyond a gain: with all of them at their lower PARAM_BOUNDS the
    # effect is only a gain (fixed, or drawn per ping), and the diagnosis does not blame it for a gap that way.
    OWN_PHYSICS: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, order: float | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if order is None:
            return  # a helper stage (e.g. the diagnosis' gain yardstick), not a catalogue effect
        if cls.name in _REGISTRY:
            raise ConfigError(f"effect {cls.name!r} registered twice ({_REGISTRY[cls.name].__name__}, {cls.__name__})")
        unknown = (set(cls.CALIBRATED) | set(cls.LOG_SCALE) | set(cls.OWN_PHYSICS)) - set(cls.PARAM_BOUNDS)
        if unknown:
            raise ConfigError(f"effect {cls.name}: calibrated/log/own-physics parameters without bounds: "
                              f"{sorted(unknown)}")
        cls.ORDER = float(order)
        _REGISTRY[cls.name] = cls

    def validate(self) -> None:
        for spec in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, spec.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"{self.name}.{spec.name}: expected a number, got {value!r}")
            low, high = self.VALID_RANGE[spec.name]
            if not math.isfinite(value) or not low <= value <= high:
                raise ConfigError(f"{self.name}.{spec.name}: {value!r} is outside the valid range [{low}, {high}]")

    def params(self) -> dict[str, Any]:
        return to_dict(self)

    @abc.abstractmethod
    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        """The stage's output for float32 amplitude `intensity` [..., n_ranges, n_beams] of `frame`."""


# ----------------------------------------------------------------------------------------------- helpers


def _planes(x: np.ndarray) -> np.ndarray:
    """View as [n_samples, n_ranges, n_beams] float32 (a copy only when the dtype differs)."""
    x = np.asarray(x, dtype=np.float32)
    return x.reshape((-1,) + x.shape[-2:])


def _filter_beams(power: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Convolve every range row with a 1-D kernel across beams (rows never mix)."""
    stacked = np.ascontiguousarray(power.reshape(-1, power.shape[-1]), dtype=np.float32)
    out = cv2.filter2D(stacked, -1, kernel.astype(np.float32).reshape(1, -1), borderType=cv2.BORDER_REFLECT_101)
    return out.reshape(power.shape)


def _filter_ranges(power: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Convolve every beam with a 1-D kernel along range (beams never mix)."""
    planes = _planes(power)
    column = kernel.astype(np.float32).reshape(-1, 1)
    out = np.stack([cv2.filter2D(np.ascontiguousarray(p), -1, column, borderType=cv2.BORDER_REFLECT_101)
                    for p in planes])
    return out.reshape(power.shape)


@remembered_draw
def _complex_gaussian(rng: np.random.Generator, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Real and imaginary parts, independent N(0, 1) float32, by Box-Muller (about twice as fast as normals)."""
    magnitude = np.sqrt(np.float32(2.0) * rng.standard_exponential(shape, dtype=np.float32))
    phase = rng.random(shape, dtype=np.float32) * np.float32(2 * math.pi)
    re, im = cv2.polarToCart(magnitude.reshape(-1, shape[-1]), phase.reshape(-1, shape[-1]))
    return re.reshape(shape), im.reshape(shape)


def _standard_normals(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """N(0, 1) float32 of `shape`, both Box-Muller outputs used."""
    size = int(np.prod(shape))
    half = (size + 1) // 2
    re, im = _complex_gaussian(rng, (1, half))
    return np.concatenate([re.ravel(), im.ravel()])[:size].reshape(shape)


def look_weights(looks: float) -> list[float]:
    """Weights of ceil(`looks`) equal, independent speckle patterns whose weighted mean has `looks` effective looks,
    (sum w)^2 / sum w^2: 1 for every pattern but the last, whose weight w in [0, 1] takes up the fraction."""
    whole = max(1, math.ceil(looks - 1e-9))
    if abs(looks - whole) < 1e-9:
        return [1.0] * whole
    # (whole - 1 + w)^2 = looks (whole - 1 + w^2), the root in [0, 1]
    a, b, c = 1.0 - looks, 2.0 * (whole - 1), (whole - 1) * (whole - 1 - looks)
    return [1.0] * (whole - 1) + [float((-b + math.sqrt(b * b - 4 * a * c)) / (2 * a))]


@remembered_draw
def _gamma_texture(rng: np.random.Generator, shape_nu: float, shape: tuple[int, ...]) -> np.ndarray:
    """Gamma(nu, 1/nu) float32 (unit mean). Above nu = 2 the Wilson-Hilferty cube of a normal matches the gamma's
    mean, variance and 1-99 % quantiles to < 1 % at a third of the cost of exact gamma draws."""
    if shape_nu < 2.0:
        return rng.standard_gamma(shape_nu, shape, dtype=np.float32) * np.float32(1.0 / shape_nu)
    z = _standard_normals(rng, shape)
    base = np.float32(1.0 - 1.0 / (9.0 * shape_nu)) + z * np.float32(1.0 / (3.0 * math.sqrt(shape_nu)))
    np.maximum(base, np.float32(0.0), out=base)
    return base * base * base


@functools.lru_cache(maxsize=32)
def _seabed_elevation_cached(ranges: bytes, azimuths: bytes, altitude_m: float, tilt_rad: float) -> np.ndarray:
    r = np.frombuffer(ranges, dtype=np.float64)
    theta = np.frombuffer(azimuths, dtype=np.float64)
    a = math.cos(tilt_rad)
    b = np.cos(theta)[None, :] * math.sin(tilt_rad)
    norm = np.sqrt(a * a + b * b)
    ratio = -altitude_m / np.maximum(r[:, None], 1e-6) / norm
    phi = np.arctan2(b, a) + np.arcsin(np.clip(ratio, -1.0, 1.0))
    phi = np.where(ratio >= -1.0, phi, -math.pi / 2)
    phi.flags.writeable = False
    return phi


def _range_bin_m(frame: SonarImage) -> float:
    # mean bin: exact for the uniform range grids every sonar uses, and far cheaper than a median
    r = frame.ranges_m
    return float(r[-1] - r[0]) / (r.size - 1) if r.size > 1 else max(float(r[0]), 1e-3)


def _sin_step(frame: SonarImage) -> float:
    """Spacing of the beams in sin(bearing): Oculus beams are equally spaced in sin, so this is one number."""
    if frame.n_beams < 2:
        return 1.0
    theta = frame.azimuths_rad
    return (math.sin(theta[-1]) - math.sin(theta[0])) / (theta.size - 1)


def _sinc2(x: np.ndarray) -> np.ndarray:
    return np.sinc(x) ** 2


def _fractional_box(width: float) -> np.ndarray:
    """A box kernel of (possibly fractional) width in samples, summing to 1; width <= 1 is the identity."""
    if width <= 1.0:
        return np.ones(1, dtype=np.float32)
    half = width / 2.0
    n = int(math.ceil(half - 0.5))
    taps = np.ones(2 * n + 1, dtype=np.float64)
    taps[[0, -1]] = half - (n - 0.5)
    return (taps / taps.sum()).astype(np.float32)


def _frame_altitude_tilt(frame: SonarImage) -> tuple[float, float]:
    return (float(frame.meta.get("sonar_altitude_m", DEFAULT_ALTITUDE_M)),
            float(frame.meta.get("sonar_tilt_rad", DEFAULT_TILT_RAD)))


def seabed_elevation(frame: SonarImage, altitude_m: float, tilt_rad: float) -> np.ndarray:
    """Elevation angle (rad, sonar frame, + up) at which a flat seabed `altitude_m` below is seen, per (range, beam).

    Solves r * (sin(phi) cos(tilt) - cos(phi) cos(theta) sin(tilt)) = -altitude for phi; where the seabed is
    out of reach (range shorter than the altitude), returns -pi/2. Cached per geometry (read-only result).
    """
    return _seabed_elevation_cached(frame.ranges_m.tobytes(), frame.azimuths_rad.tobytes(), float(altitude_m),
                                    float(tilt_rad))


# ----------------------------------------------------------------------------------------------- effects


@dataclass(frozen=True)
class Speckle(Effect, order=30):
    """Coherent speckle: many sub-resolution scatterers per cell add with random phases.

    The field of a cell is circular complex Gaussian (Rayleigh amplitude); a gamma-distributed texture of
    shape `shape_nu` multiplies the intensity, giving K-distributed intensity (SI = 1 + 2/nu; nu -> inf is
    Rayleigh, small nu = patchy, heavy-tailed seabed). The complex field is low-pass filtered with a Gaussian of
    `grain_beams` x `grain_ranges` pixels (sigma), the resolution cell, so the grain is anisotropic like a real
    FLS (about two beams across, one bin along range). Mean power is preserved.

    A sensor that averages intensities before it reports them (sub-bands, overlapping beams, several pings) shows
    speckle lighter than Rayleigh: `looks` independent speckle patterns averaged (SI = 1/looks under the texture).
    A fraction of a look is the last pattern weighted down so the average has exactly that many looks' SI.

    Speckle is deterministic given the scatterers: for a static scene it is frozen. A frame whose meta carries
    `speckle_seed` (the simulator derives it from scene seed + pose) draws the field from that seed, so the same
    scene and pose give the same speckle and a moving sonar decorrelates it; otherwise `rng` is used.
    """

    name: ClassVar[str] = "speckle"
    shape_nu: float = 28.2  # calibrated
    grain_beams: float = 1.91  # calibrated
    grain_ranges: float = 0.6
    looks: float = 1.0
    # looks last: a search first matches the grain, then how much lighter than Rayleigh it is
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "shape_nu": (0.5, 50.0), "grain_beams": (0.3, 4.0), "grain_ranges": (0.3, 4.0), "looks": (1.0, 8.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "shape_nu": (0.05, 1e6), "grain_beams": (0.0, 50.0), "grain_ranges": (0.0, 50.0), "looks": (1.0, 64.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("shape_nu", "grain_beams", "grain_ranges")
    LOG_SCALE: ClassVar[frozenset[str]] = frozenset({"shape_nu"})

    # Above this shape the gamma texture is indistinguishable from 1 (SI change < 0.2 %).
    RAYLEIGH_LIMIT_NU: ClassVar[float] = 1000.0

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        seed = frame.meta.get("speckle_seed")
        source = np.random.default_rng(int(seed)) if seed is not None else rng
        planes = _planes(intensity)
        out = np.empty_like(planes)
        for i, plane in enumerate(planes):
            power = self.pattern(source, plane.shape)
            texture = (_gamma_texture(source, self.shape_nu, plane.shape)
                       if self.shape_nu < self.RAYLEIGH_LIMIT_NU else None)
            if self.looks > 1.0:  # drawn after the texture: one look keeps the draws it always had
                power = self._pattern_mean(power, source, plane.shape)
            if texture is not None:
                power *= texture
            out[i] = plane * np.sqrt(power)
        return out.reshape(intensity.shape)

    def pattern(self, source: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """One speckle pattern: the power of a complex Gaussian field filtered to the resolution cell, unit mean."""
        return _speckle_pattern(source, shape, self.grain_beams, self.grain_ranges)

    def _pattern_mean(self, first: np.ndarray, source: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """The weighted mean (`look_weights`) of `first` and further independent patterns: SI 1/looks."""
        weights = look_weights(self.looks)
        for weight in weights[1:]:
            first += np.float32(weight) * self.pattern(source, shape)
        return first / np.float32(sum(weights))


@remembered_draw
def _speckle_pattern(rng: np.random.Generator, shape: tuple[int, ...], grain_beams: float,
                     grain_ranges: float) -> np.ndarray:
    re, im = _complex_gaussian(rng, shape)
    if grain_beams <= 0 and grain_ranges <= 0:
        return (re * re + im * im) / np.float32(2.0)
    sx, sy = max(grain_beams, 1e-3), max(grain_ranges, 1e-3)
    kx = cv2.getGaussianKernel(2 * int(math.ceil(3 * sx)) + 1, sx, cv2.CV_32F)
    ky = cv2.getGaussianKernel(2 * int(math.ceil(3 * sy)) + 1, sy, cv2.CV_32F)
    gain = float((kx ** 2).sum() * (ky ** 2).sum())  # variance kept by the filter
    re = cv2.sepFilter2D(re, -1, kx, ky, borderType=cv2.BORDER_REFLECT_101)
    im = cv2.sepFilter2D(im, -1, kx, ky, borderType=cv2.BORDER_REFLECT_101)
    return (re * re + im * im) / np.float32(2.0 * gain)


@dataclass(frozen=True)
class BeamSidelobes(Effect, order=50):
    """Horizontal receive beam pattern and cross-talk: bright returns smear along their constant-range arc.

    A line array's power pattern is sinc^2 in sin(bearing); Oculus beams are equally spaced in sin(bearing),
    so the pattern is one shift-invariant kernel across beams. `mainlobe_deg` is the -3 dB width at boresight
    (0.6 deg at 1.2 MHz), `sidelobe_db` the first sidelobe level (-13.3 dB unshaded; shading lowers it; the
    whole sidelobe region is scaled by the same factor) and `crosstalk_db` the flat pedestal that element errors
    and cross-talk put under each return, across every beam of its row, relative to that return (a point echo of
    power P lifts every beam of its row by P * 10^(crosstalk_db/10); so the level does not depend on the number of
    beams, and an equal-ripple pattern's far sidelobes are a pedestal). Only constant-range rows mix.
    """

    name: ClassVar[str] = "beam_sidelobes"
    mainlobe_deg: float = 0.6
    sidelobe_db: float = -38.7  # calibrated
    # The pedestal's search range is the one it had relative to the row mean at 256 beams: reaching up to -15 dB
    # re each return moved no validation outcome the right way on balance (the commit 900036c says so; that session
    # left no figures, and this reach's are in docs/RESULTS.md, 2026-11-27).
    crosstalk_db: float = -60.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "mainlobe_deg": (0.2, 3.0), "sidelobe_db": (-45.0, -10.0), "crosstalk_db": (-84.0, -39.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "mainlobe_deg": (0.01, 30.0), "sidelobe_db": (-120.0, 0.0), "crosstalk_db": (-200.0, 0.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("sidelobe_db",)

    # Sidelobes kept on each side of the mainlobe (the pattern decays as 1/u^2; further ones are < -40 dB).
    N_SIDELOBES: ClassVar[int] = 12

    def kernel(self, frame: SonarImage) -> np.ndarray:
        """Power pattern across beams (sums to 1)."""
        first_null = math.sin(math.radians(self.mainlobe_deg)) / 0.886  # sinc^2 -3 dB full width = 0.886 null
        u_null = first_null / _sin_step(frame)  # in beams
        half = int(min(math.ceil((self.N_SIDELOBES + 1) * u_null), frame.n_beams - 1))
        x = np.arange(-half, half + 1) / u_null
        pattern = _sinc2(x)
        # sinc^2's own first sidelobe is -13.26 dB; rescale every sidelobe to the requested level.
        sidelobe_scale = 10 ** ((self.sidelobe_db + 13.26) / 10)
        pattern = np.where(np.abs(x) >= 1.0, pattern * sidelobe_scale, pattern)
        return (pattern / pattern.sum()).astype(np.float32)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        power = np.square(intensity, dtype=np.float32)
        smeared = _filter_beams(power, self.kernel(frame))
        pedestal = np.float32(10 ** (self.crosstalk_db / 10))
        smeared += pedestal * power.sum(axis=-1, keepdims=True)
        # a wide kernel's rounding leaves tiny negative powers beside dark cells: clip them, or sqrt makes NaN
        return np.sqrt(np.maximum(smeared, 0.0, out=smeared))


@dataclass(frozen=True)
class RangeBlur(Effect, order=60):
    """Range point-spread function: pulse length (or compressed-pulse width) and range sidelobes.

    The detected echo of a point is the pulse envelope: a Gaussian of FWHM `resolution_m` (c*tau/2 or c/2B;
    about 3 mm for an Oculus, smaller than a typical simulation bin, so the default blurs about one bin), plus
    a pair of range sidelobes at +-1.5 resolutions of level `sidelobe_db` (matched-filter ringing). Only the
    range axis mixes.
    """

    name: ClassVar[str] = "range_blur"
    resolution_m: float = 0.03
    sidelobe_db: float = -10.3  # calibrated
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "resolution_m": (0.002, 0.3), "sidelobe_db": (-50.0, -10.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "resolution_m": (1e-4, 10.0), "sidelobe_db": (-200.0, 0.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("resolution_m", "sidelobe_db")
    LOG_SCALE: ClassVar[frozenset[str]] = frozenset({"resolution_m"})

    def kernel(self, frame: SonarImage) -> np.ndarray:
        """Power PSF along range, in bins (sums to 1)."""
        width = self.resolution_m / _range_bin_m(frame)
        sigma = max(width / 2.355, 1e-3)
        sidelobe_offset = 1.5 * max(width, 1.0)
        half = int(math.ceil(max(3 * sigma, sidelobe_offset + 2 * sigma)))
        x = np.arange(-half, half + 1, dtype=np.float64)
        main = np.exp(-0.5 * (x / sigma) ** 2)
        main /= main.max()
        side_sigma = max(sigma, 0.5)
        lobes = sum(np.exp(-0.5 * ((x - s) / side_sigma) ** 2) for s in (-sidelobe_offset, sidelobe_offset))
        pattern = main + 10 ** (self.sidelobe_db / 10) * lobes
        return (pattern / pattern.sum()).astype(np.float32)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        power = np.square(intensity, dtype=np.float32)
        return np.sqrt(_filter_ranges(power, self.kernel(frame)))


@dataclass(frozen=True)
class TvgNoise(Effect, order=70):
    """Time-varying gain and the electronic noise floor it amplifies with range.

    Echoes lose `tvg_log_coeff_db`*log10(r) to spreading and 2*`absorption_db_per_m`*r to absorption; the TVG
    G(r) undoes both for the signal (up to `residual_ramp_db`, a gain error growing linearly from 0 at the
    first bin to that many dB at the last). Electronic noise enters after the losses, so TVG amplifies it:
    complex Gaussian noise (new every ping, correlated across beams by the beamformer) of rms
    `noise_amplitude` at the maximum range and rms scaled by G(r)/G(r_max) nearer in. Signal and noise add as
    phasors: A_out = |A * ramp(r) + n(r)|. Receive channels differ in noise figure: each beam's noise rms is
    scaled by a log-normal of rms `beam_noise_contrast` (natural log, drawn each ping), so the noise floor is
    striped where nothing brighter covers it (the water column) and the lit seabed is not.
    """

    name: ClassVar[str] = "tvg_noise"
    noise_amplitude: float = 0.12
    tvg_log_coeff_db: float = 15.2  # calibrated
    absorption_db_per_m: float = 0.5
    residual_ramp_db: float = -0.562  # calibrated
    beam_noise_contrast: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "noise_amplitude": (0.0, 0.5), "tvg_log_coeff_db": (10.0, 40.0), "absorption_db_per_m": (0.0, 2.0),
        "residual_ramp_db": (-12.0, 12.0), "beam_noise_contrast": (0.0, 1.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "noise_amplitude": (0.0, 10.0), "tvg_log_coeff_db": (0.0, 80.0), "absorption_db_per_m": (0.0, 10.0),
        "residual_ramp_db": (-60.0, 60.0), "beam_noise_contrast": (0.0, 3.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("noise_amplitude", "tvg_log_coeff_db", "residual_ramp_db",
                                             "beam_noise_contrast")
    OWN_PHYSICS: ClassVar[tuple[str, ...]] = ("noise_amplitude",)  # without noise: a gain curve over range

    # Beamforming correlates the noise across about one beam (sigma in beams).
    NOISE_GRAIN_BEAMS: ClassVar[float] = 0.7

    def noise_profile(self, frame: SonarImage) -> np.ndarray:
        """rms of the noise after TVG per range bin (= noise_amplitude at the last bin)."""
        r = np.maximum(frame.ranges_m, 1e-3)
        r_max = r[-1]
        gain_db = self.tvg_log_coeff_db * np.log10(r / r_max) + 2 * self.absorption_db_per_m * (r - r_max)
        return (self.noise_amplitude * 10 ** (gain_db / 20)).astype(np.float32)

    def signal_ramp(self, frame: SonarImage) -> np.ndarray:
        r = frame.ranges_m
        span = max(r[-1] - r[0], 1e-9)
        return (10 ** (self.residual_ramp_db * (r - r[0]) / span / 20)).astype(np.float32)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        planes = _planes(intensity)
        ramp = self.signal_ramp(frame)[:, None]
        profile = self.noise_profile(frame)[:, None]
        kx = cv2.getGaussianKernel(5, self.NOISE_GRAIN_BEAMS, cv2.CV_32F)
        gain = np.float32(math.sqrt(2.0 * float((kx ** 2).sum())))  # per-component rms -> noise rms of 1
        one = np.ones((1, 1), np.float32)
        out = np.empty_like(planes)
        for i, plane in enumerate(planes):
            noise_re, noise_im = _complex_gaussian(rng, plane.shape)
            scale = profile / gain
            if self.beam_noise_contrast > 0:  # drawn only when on: without it the ping's draws stay as they were
                scale = scale * np.exp(np.float32(self.beam_noise_contrast)
                                       * rng.standard_normal(plane.shape[-1]).astype(np.float32))[None, :]
            re = cv2.sepFilter2D(noise_re, -1, kx, one, borderType=cv2.BORDER_REFLECT_101) * scale
            im = cv2.sepFilter2D(noise_im, -1, kx, one, borderType=cv2.BORDER_REFLECT_101) * scale
            re += plane * ramp
            out[i] = np.sqrt(re * re + im * im)
        return out.reshape(intensity.shape)


# arcsin(x) = pi/2 - sqrt(1 - x) * poly(x) on [0, 1], |error| <= 2e-8 rad (Abramowitz & Stegun 4.4.46): in float32
# a fifth of the cost of numpy's arcsin, which has no vectorised float32 loop on this CPU class
_ASIN_POLY = (1.5707963050, -0.2145988016, 0.0889789874, -0.0501743046, 0.0308918810, -0.0170881256, 0.0066700901,
              -0.0012624911)


def _arcsin32(x: np.ndarray) -> np.ndarray:
    """arcsin of float32 x in [-1, 1], float32, to ~2e-7 rad."""
    a = np.abs(x)
    poly = np.full_like(a, np.float32(_ASIN_POLY[-1]))
    for coeff in _ASIN_POLY[-2::-1]:
        poly *= a
        poly += np.float32(coeff)
    np.subtract(np.float32(1.0), a, out=a)
    np.sqrt(a, out=a)
    a *= poly
    np.subtract(np.float32(math.pi / 2), a, out=a)
    return np.copysign(a, x, out=a)


@functools.lru_cache(maxsize=8)
def _elevation_tables(ranges: bytes, azimuths: bytes, tilt_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """What seabed_elevation() needs besides the altitude, float32: -1/(r * norm) per (range, beam) and delta per
    beam, so that phi = delta + asin(altitude * that) (see seabed_elevation)."""
    r = np.frombuffer(ranges, dtype=np.float64)
    theta = np.frombuffer(azimuths, dtype=np.float64)
    a = math.cos(tilt_rad)
    b = np.cos(theta)[None, :] * math.sin(tilt_rad)
    norm = np.sqrt(a * a + b * b)
    per_altitude = (-1.0 / np.maximum(r[:, None], 1e-6) / norm).astype(np.float32)
    delta = np.arctan2(b, a).astype(np.float32)
    per_altitude.flags.writeable = False
    delta.flags.writeable = False
    return per_altitude, delta


@functools.lru_cache(maxsize=32)
def _vertical_weight(ranges: bytes, azimuths: bytes, altitude_m: float, tilt_rad: float, beamwidth_deg: float,
                     floor_db: float) -> np.ndarray:
    """seabed_elevation()'s angle through the pattern, in float32 (a new altitude every ping makes this per frame)."""
    per_altitude, delta = _elevation_tables(ranges, azimuths, tilt_rad)
    ratio = per_altitude * np.float32(altitude_m)
    out_of_reach = ratio < -1.0  # range shorter than the altitude: taken as straight down, like seabed_elevation
    phi = _arcsin32(np.clip(ratio, np.float32(-1.0), np.float32(1.0), out=ratio))
    phi += delta
    # one-way power sinc^2(0.886 phi_deg / beamwidth) = (sin(y) / y)^2 with y = pi * 0.886 phi_deg / beamwidth
    scale = np.float32(0.886 * 180.0 / beamwidth_deg)
    y = np.abs(phi, out=phi)
    y *= scale
    np.copyto(y, scale * np.float32(math.pi / 2), where=out_of_reach)
    np.maximum(y, np.float32(1e-20), out=y)
    weight = np.sin(y)
    weight /= y
    weight *= weight
    # two-way power = one_way_power^2, so the amplitude weight is one_way_power itself
    np.maximum(weight, np.float32(10 ** (floor_db / 20)), out=weight)
    weight.flags.writeable = False
    return weight


@dataclass(frozen=True)
class ElevationSpread(Effect, order=10):
    """Vertical beam pattern: returns weighted by where in the vertical fan they arrive from.

    A ray-cast sensor treats the vertical aperture as a box; a real transducer's two-way vertical pattern
    is sinc^4-like (one-way power sinc^2, -3 dB at +-`beamwidth_deg`/2), falling below the box at the edges
    and never below the sidelobe floor `floor_db` (amplitude). A flat seabed at the frame's altitude and tilt
    (meta `sonar_altitude_m`, `sonar_tilt_rad`) is seen at a known elevation per (range, beam), so every pixel
    is scaled by the pattern at that elevation: a multiplicative, range-shaped weighting (the seabed band's
    profile) that moves no energy between pixels.
    """

    name: ClassVar[str] = "elevation_spread"
    beamwidth_deg: float = 16.5  # calibrated
    floor_db: float = -26.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "beamwidth_deg": (6.0, 40.0), "floor_db": (-40.0, -6.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "beamwidth_deg": (0.5, 90.0), "floor_db": (-200.0, 0.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("beamwidth_deg",)

    def weight(self, frame: SonarImage) -> np.ndarray:
        """Amplitude weight per (range, beam): the two-way vertical pattern at the seabed's elevation."""
        altitude, tilt = _frame_altitude_tilt(frame)
        return _vertical_weight(frame.ranges_m.tobytes(), frame.azimuths_rad.tobytes(), altitude, tilt,
                                self.beamwidth_deg, self.floor_db)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        return intensity * self.weight(frame)


@dataclass(frozen=True)
class Multipath(Effect, order=20):
    """Multipath ghosts: weaker copies of the scene at longer range and the same bearing.

    A path that bounces off the sea surface, the seabed or a tank wall arrives later; with the image method the
    extra apparent range of a ghost is about the same for a scene (`ghost_offset_m`), and each further bounce
    adds the same offset (the comb of parallel arcs seen in tanks). Ghost k has amplitude
    `reflection_coeff`^k. Ghosts add power only at ranges beyond the direct return.

    Where a ghost overlaps a direct return the two fields interfere with a phase that changes from cell to cell
    (the two paths differ by many wavelengths). `coherence` scales that interference term, 2 sqrt(P_direct
    P_ghost) cos(phase): 0 adds the powers (many scatterers averaged within a cell: a smooth ghost), 1 is two
    phasors of random relative phase (a ghost that carries its own speckle over the direct return).
    """

    name: ClassVar[str] = "multipath"
    reflection_coeff: float = 0.2
    ghost_offset_m: float = 1.5
    n_ghosts: int = 1
    coherence: float = 0.0
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "reflection_coeff": (0.0, 0.8), "ghost_offset_m": (0.1, 10.0), "coherence": (0.0, 1.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "reflection_coeff": (0.0, 1.0), "ghost_offset_m": (1e-3, 1e4), "n_ghosts": (0, 10), "coherence": (0.0, 1.0)}

    def validate(self) -> None:
        super().validate()
        if not isinstance(self.n_ghosts, int):
            raise ConfigError(f"multipath.n_ghosts: expected an integer, got {self.n_ghosts!r}")

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        power = np.square(intensity, dtype=np.float32)
        out = power.copy()
        shift_bins = self.ghost_offset_m / _range_bin_m(frame)
        for k in range(1, self.n_ghosts + 1):
            shift = k * shift_bins
            whole = int(math.floor(shift))
            if whole >= frame.n_ranges:
                break
            frac = np.float32(shift - whole)
            scale = np.float32(self.reflection_coeff ** (2 * k))
            # linear interpolation between the two integer shifts keeps sub-bin offsets exact in energy
            out[..., whole:, :] += scale * (1 - frac) * power[..., :frame.n_ranges - whole, :]
            if whole + 1 < frame.n_ranges:
                out[..., whole + 1:, :] += scale * frac * power[..., :frame.n_ranges - whole - 1, :]
        if self.coherence > 0:  # no draws otherwise, and the sum as before: frames without it stay bit for bit
            ghosts = out - power
            phase = rng.uniform(0.0, 2 * math.pi, size=power.shape).astype(np.float32)
            out += np.float32(2 * self.coherence) * np.sqrt(power * ghosts) * np.cos(phase)
            np.maximum(out, 0.0, out=out)
        return np.sqrt(out)


@functools.lru_cache(maxsize=32)
def _shear_maps(ranges: bytes, azimuths: bytes, yaw_rate_rad_s: float) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap tables of the yaw shear: the return heard at range r came from bearing theta + yaw * 2r/c."""
    r = np.frombuffer(ranges, dtype=np.float64)
    theta = np.frombuffer(azimuths, dtype=np.float64)
    seen_at = theta[None, :] + (yaw_rate_rad_s * 2 * r / SOUND_SPEED_MPS)[:, None]
    map_x = np.interp(seen_at, theta, np.arange(theta.size, dtype=np.float64), left=-1.0, right=theta.size)
    map_y = np.broadcast_to(np.arange(r.size, dtype=np.float32)[:, None], map_x.shape)
    return map_x.astype(np.float32), np.ascontiguousarray(map_y)


@dataclass(frozen=True)
class MotionBlur(Effect, order=40):
    """Platform motion during a ping.

    All beams come from one transmission but range r is heard at t = 2r/c: a yaw rate `yaw_rate_deg_s` shears
    the image, shifting each row's bearing by yaw_rate*2r/c (more at long range). The image is also the
    average over an integration window `integration_s` (receiver averaging, ping-to-ping filtering), during
    which the sonar turns by yaw_rate*integration_s (smear across beams) and moves `surge_m_s`*integration_s
    (smear along range). With `looks` of 2 or more (rounded) the window is not continuous but that many pings,
    evenly spread over it, averaged (ping-to-ping averaging): an echo is repeated `looks` times across the beams
    (a double image for 2), where the continuous window smears it into a band. Below 2 the window is continuous.
    """

    name: ClassVar[str] = "motion_blur"
    yaw_rate_deg_s: float = 10.0
    surge_m_s: float = 0.3
    integration_s: float = 0.05
    looks: float = 0.0
    # looks last: it only matters once the window spans a few beams
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "yaw_rate_deg_s": (-60.0, 60.0), "surge_m_s": (0.0, 2.0), "integration_s": (0.0, 0.3), "looks": (0.0, 8.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "yaw_rate_deg_s": (-720.0, 720.0), "surge_m_s": (-20.0, 20.0), "integration_s": (0.0, 10.0),
        "looks": (0.0, 64.0)}

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        yaw_rate = math.radians(self.yaw_rate_deg_s)
        map_x, map_y = _shear_maps(frame.ranges_m.tobytes(), frame.azimuths_rad.tobytes(), yaw_rate)
        beam_step = frame.fov_rad / (frame.n_beams - 1) if frame.n_beams > 1 else 1.0
        width_beams = abs(yaw_rate) * self.integration_s / beam_step
        width_ranges = abs(self.surge_m_s) * self.integration_s / _range_bin_m(frame)
        looks = int(round(self.looks))
        smear_beams, smear_ranges = _fractional_box(width_beams), _fractional_box(width_ranges)
        smeared = smear_beams.size > 1 or smear_ranges.size > 1
        planes = _planes(intensity)
        out = np.empty_like(planes)
        for i, plane in enumerate(planes):
            power = cv2.remap(plane * plane, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            if looks >= 2:
                power = _average_looks(power, looks, width_beams, width_ranges)
            elif smeared:
                power = cv2.sepFilter2D(power, -1, smear_beams, smear_ranges, borderType=cv2.BORDER_REFLECT_101)
            out[i] = np.sqrt(np.maximum(power, 0))
        return out.reshape(intensity.shape)


def _average_looks(power: np.ndarray, looks: int, width_beams: float, width_ranges: float) -> np.ndarray:
    """The mean of `looks` copies of `power` spread evenly over a window of the given widths, centred as the
    continuous window's box is (the edges reflected, as its filter does)."""
    total = np.zeros_like(power)
    for position in np.linspace(-0.5, 0.5, looks):
        shift = np.float32([[1, 0, position * width_beams], [0, 1, position * width_ranges]])
        total += cv2.warpAffine(power, shift, (power.shape[1], power.shape[0]), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REFLECT_101)
    return total / np.float32(looks)


@dataclass(frozen=True)
class RingDown(Effect, order=90):
    """Transmit ring-down: the receiver still rings from the transmit pulse at the first range bins.

    Adds a full-width band of power amplitude^2 * exp(-2 (r - r_0)/`decay_m`) (amplitude decays with e-folding
    `decay_m` from the first bin r_0), modulated per beam by `beam_ripple` (relative rms, new every ping: the
    element-to-element spread of the leakage). With `rise_m` > 0 the receiver's gain recovers from the transmit
    blanking over `rise_m` (e-folding) while the ring decays: the band's amplitude is multiplied by
    1 - exp(-(r - r_0)/`rise_m`), so it starts dark, peaks some tens of centimetres out and fades (the Oculus
    recording's near-field band: `calibrate.match_near_field` fits the rise; the diagnosis keeps the catalogue's
    rise of 0, so it is not in PARAM_BOUNDS). Beyond the range where the band falls under 1e-4 of `amplitude`
    nothing changes.
    """

    name: ClassVar[str] = "ring_down"
    amplitude: float = 0.139  # calibrated
    decay_m: float = 0.0418  # calibrated
    beam_ripple: float = 0.25
    rise_m: float = 0.0
    # the decay before the amplitude: a fit sweeps them in this order, and at the calibrated short decay a long
    # real ring-down is matched best by no ring-down at all (amplitude 0), after which no decay changes anything
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "decay_m": (0.005, 0.5), "beam_ripple": (0.0, 0.8), "amplitude": (0.0, 1.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "amplitude": (0.0, 10.0), "decay_m": (1e-5, 100.0), "beam_ripple": (0.0, 5.0), "rise_m": (0.0, 100.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("amplitude", "decay_m")
    LOG_SCALE: ClassVar[frozenset[str]] = frozenset({"decay_m"})

    def band(self, frame: SonarImage) -> np.ndarray:
        """Ring-down amplitude per range bin (zero where below 1e-4 of `amplitude`)."""
        r = frame.ranges_m - frame.ranges_m[0]
        band = self.amplitude * np.exp(-r / self.decay_m)
        if self.rise_m > 0:
            band = band * -np.expm1(-r / self.rise_m)
        return np.where(band >= 1e-4 * self.amplitude, band, 0.0).astype(np.float32)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        band = self.band(frame)
        lit = np.flatnonzero(band)
        out = np.array(intensity, dtype=np.float32, copy=True)
        if lit.size == 0:
            return out
        rows = int(lit[-1]) + 1  # with a rise the first bins are dark: the band ends at its last lit bin
        planes = _planes(out)
        for plane in planes:
            ripple = np.maximum(1.0 + self.beam_ripple * rng.standard_normal(frame.n_beams), 0.0)
            leak = band[:rows, None] * ripple[None, :].astype(np.float32)
            plane[:rows] = np.sqrt(plane[:rows] ** 2 + leak ** 2)
        return planes.reshape(intensity.shape)


@dataclass(frozen=True)
class WaterColumn(Effect, order=75):
    """What the water column shows between the transducer and the seabed: volume reverberation and beam stripes.

    Suspended particles and plankton back-scatter weakly everywhere: a speckled haze of rms amplitude
    `haze_level` (after TVG, so flat in range) that fills the rows above the seabed return. Each beam's receive
    chain has its own gain error, fixed over a ping: a log-normal gain of rms `stripe_contrast` (natural log),
    correlated over `stripe_width_beams` beams, multiplies haze and signal alike, so vertical stripes run down
    the whole fan and show most where nothing else does (the water column).
    """

    name: ClassVar[str] = "water_column"
    haze_level: float = 0.02
    stripe_contrast: float = 0.15
    stripe_width_beams: float = 1.5
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "haze_level": (0.0, 0.3), "stripe_contrast": (0.0, 0.8), "stripe_width_beams": (0.3, 8.0)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "haze_level": (0.0, 10.0), "stripe_contrast": (0.0, 3.0), "stripe_width_beams": (0.0, 100.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("haze_level", "stripe_contrast")
    OWN_PHYSICS: ClassVar[tuple[str, ...]] = ("haze_level",)  # without haze: random per-beam gains only

    def beam_gain(self, n_beams: int, rng: np.random.Generator) -> np.ndarray:
        """Per-beam amplitude gain of one ping (log-normal, unit median)."""
        white = rng.standard_normal(n_beams + 16).astype(np.float32)
        if self.stripe_width_beams > 0.3:
            kernel = cv2.getGaussianKernel(2 * int(math.ceil(3 * self.stripe_width_beams)) + 1,
                                           self.stripe_width_beams, cv2.CV_32F).ravel()
            white = np.convolve(white, kernel / math.sqrt(float((kernel ** 2).sum())), mode="same")
        return np.exp(np.float32(self.stripe_contrast) * white[8:8 + n_beams]).astype(np.float32)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        planes = _planes(intensity)
        out = np.empty_like(planes)
        level = np.float32(self.haze_level / math.sqrt(2.0))
        for i, plane in enumerate(planes):
            gain = self.beam_gain(frame.n_beams, rng)[None, :]
            re, im = _complex_gaussian(rng, plane.shape)
            re *= level
            im *= level
            re += plane
            out[i] = np.sqrt(re * re + im * im) * gain
        return out.reshape(intensity.shape)


@dataclass(frozen=True)
class Interference(Effect, order=80):
    """Pulses from other acoustic sources (another sonar, a DVL) arriving out of sync with our pings.

    Events per ping are Poisson with mean `rate_per_ping`; each lands at a uniform random apparent range
    (c*t/2) and source bearing, with power amplitude^2 shaped in range by the pulse (Gaussian, FWHM
    `thickness_m`) and across beams by the beam pattern around the source bearing on top of a flat floor
    `floor_db` (the direct arrival leaks through every sidelobe) - so a thin arc across the whole fan that
    moves from ping to ping.
    """

    name: ClassVar[str] = "interference"
    rate_per_ping: float = 0.3
    amplitude: float = 0.5
    floor_db: float = -15.0
    thickness_m: float = 0.05
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {
        "rate_per_ping": (0.0, 3.0), "amplitude": (0.0, 1.0), "floor_db": (-40.0, -3.0),
        "thickness_m": (0.005, 0.5)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {
        "rate_per_ping": (0.0, 100.0), "amplitude": (0.0, 10.0), "floor_db": (-200.0, 0.0),
        "thickness_m": (1e-4, 100.0)}

    # Angular width (sigma, deg) of the direct arrival's mainlobe around the source bearing.
    SOURCE_WIDTH_DEG: ClassVar[float] = 2.0

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        planes = _planes(intensity)
        out = planes.copy()
        floor = 10 ** (self.floor_db / 10)
        sigma_r = max(self.thickness_m / 2.355, 1e-6)
        for plane_out in out:
            n_events = int(rng.poisson(self.rate_per_ping))
            if n_events == 0:
                continue
            added = np.zeros_like(plane_out)
            for _ in range(n_events):
                at_range = rng.uniform(frame.ranges_m[0], frame.ranges_m[-1])
                source = rng.uniform(frame.azimuths_rad[0], frame.azimuths_rad[-1])
                across = floor + (1 - floor) * np.exp(
                    -0.5 * (np.degrees(frame.azimuths_rad - source) / self.SOURCE_WIDTH_DEG) ** 2)
                rows = np.nonzero(np.abs(frame.ranges_m - at_range) <= 4 * sigma_r)[0]
                if rows.size == 0:
                    rows = np.array([int(np.argmin(np.abs(frame.ranges_m - at_range)))])
                along = np.exp(-0.5 * ((frame.ranges_m[rows] - at_range) / sigma_r) ** 2)
                added[rows] += (self.amplitude ** 2 * along[:, None] * across[None, :]).astype(np.float32)
            np.sqrt(plane_out ** 2 + added, out=plane_out)
        return out.reshape(intensity.shape)


@dataclass(frozen=True)
class GammaQuantization(Effect, order=100):
    """The sensor's output mapping: gain, gamma, 8-bit quantisation with saturation.

    v = clip(round(255 * (gain * A)^gamma), 0, 255). gamma ~0.5 (Oculus gamma code 127) makes Rayleigh
    amplitude Weibull with k = 2/gamma (CV 0.28), lifts weak sidelobes and noise, and saturates bright
    specular returns at 255. Returns uint8.
    """

    name: ClassVar[str] = "gamma_quantization"
    gain: float = 1.0
    gamma: float = 0.6
    PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"gain": (0.2, 5.0), "gamma": (0.25, 1.2)}
    VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {"gain": (1e-6, 1e6), "gamma": (0.01, 5.0)}
    CALIBRATED: ClassVar[tuple[str, ...]] = ("gamma",)

    def apply(self, intensity: np.ndarray, frame: SonarImage, rng: np.random.Generator) -> np.ndarray:
        counts = self.level(intensity)
        # float -> uint8 conversion by cv2 rounds to nearest and saturates at 0 and 255 in one pass
        return cv2.convertScaleAbs(counts.reshape(-1, counts.shape[-1]), alpha=255.0).reshape(counts.shape)

    def level(self, intensity: np.ndarray) -> np.ndarray:
        """(gain * A)^gamma as float32, before quantisation and saturation (1.0 = full scale)."""
        scaled = np.maximum(np.asarray(intensity, dtype=np.float32) * np.float32(self.gain), 0)
        return cv2.pow(scaled.reshape(-1, scaled.shape[-1]), self.gamma).reshape(scaled.shape)


# ----------------------------------------------------------------------------------------------- catalogue

# Physical order of the forward model (each class's `order=`): what the scene sends back (vertical pattern,
# extra paths), the coherent sum (speckle), geometry during the ping, the beamformer and pulse PSFs, the receiver
# (TVG + noise), what arrives outside the scene (interference, ring-down), and last the output mapping.
PIPELINE_ORDER: tuple[str, ...] = tuple(sorted(_REGISTRY, key=lambda name: _REGISTRY[name].ORDER))
# Registration (definition) order: the calibration's search visits parameters in it.
EFFECTS: dict[str, type[Effect]] = dict(_REGISTRY)


def calibrated_parameters() -> tuple[tuple[str, str, bool], ...]:
    """(effect, parameter, log-scale search) for every parameter the calibration refits, from the registry."""
    return tuple((name, param, param in cls.LOG_SCALE) for name, cls in EFFECTS.items() for param in cls.CALIBRATED)


def make_effect(name: str, **params: Any) -> Effect:
    """Build an effect by canonical name with parameter overrides (validated; ConfigError on anything wrong)."""
    if name not in EFFECTS:
        raise ConfigError(f"unknown effect {name!r}; known effects: {', '.join(PIPELINE_ORDER)}")
    cls = EFFECTS[name]
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    # Integer parameters given as whole floats (from CLI or JSON) are accepted.
    for key, value in list(params.items()):
        if key in fields and fields[key].type in (int, "int") and isinstance(value, float) and value.is_integer():
            params[key] = int(value)
    return from_dict(cls, params, where=name)


def resolve_effects(spec: str | Sequence[str | Effect] | None, overrides: dict[str, dict[str, Any]] | None = None,
                    ) -> list[Effect]:
    """Effects from "none", "all", "a,b", a list of names or instances; `overrides` maps name -> params."""
    overrides = dict(overrides or {})
    if spec is None or spec == "none":
        names_or_effects: list[str | Effect] = []
    elif spec == "all":
        names_or_effects = list(PIPELINE_ORDER)
    elif isinstance(spec, str):
        names_or_effects = [n.strip() for n in spec.split(",") if n.strip()]
    else:
        names_or_effects = list(spec)
    effects: list[Effect] = []
    for item in names_or_effects:
        if isinstance(item, Effect):
            changes = overrides.pop(item.name, None)
            effects.append(item if changes is None else make_effect(item.name, **{**item.params(), **changes}))
        elif isinstance(item, str):
            effects.append(make_effect(item, **overrides.pop(item, {})))
        else:
            raise ConfigError(f"effects: expected names or effect instances, got {type(item).__name__}")
    unknown = sorted(name for name in overrides if name not in EFFECTS)
    if unknown:
        raise ConfigError(f"parameters given for unknown effect(s) {', '.join(unknown)}; known effects: "
                          f"{', '.join(PIPELINE_ORDER)}")
    if overrides:
        raise ConfigError(f"parameters given for effect(s) not selected: {', '.join(sorted(overrides))}")
    names = [e.name for e in effects]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ConfigError(f"effects: {', '.join(duplicates)} selected more than once")
    return sorted(effects, key=lambda e: PIPELINE_ORDER.index(e.name))


def apply_effects(frame: SonarImage, effects: Sequence[Effect], rng: np.random.Generator) -> SonarImage:
    """Apply `effects` to `frame` in PIPELINE_ORDER; the result's meta lists the effects and their parameters.

    Without gamma_quantization the result is float32 linear amplitude (>= 0); with it, uint8 counts.
    """
    ordered = resolve_effects(list(effects))
    # integer frames to [0, 1]; float frames scaled but not clipped (an earlier stage may have gone above 1)
    intensity = (frame.intensity.astype(np.float32) / np.float32(frame.intensity_scale)
                 if frame.intensity.dtype.kind == "f" else frame.normalized())
    for effect in ordered:
        intensity = effect.apply(intensity, frame, rng)
    meta = dict(frame.meta)
    meta["effects"] = list(meta.get("effects", [])) + [{"name": e.name, "params": e.params()} for e in ordered]
    if intensity.dtype == np.uint8:
        return frame.replace(intensity=intensity, intensity_scale=255.0, meta=meta)
    return frame.replace(intensity=np.maximum(intensity, 0).astype(np.float32), intensity_scale=1.0, meta=meta)
