"""Held-out vertical beam patterns: a Hann-shaded aperture with a pointing error, and a flat-topped pattern that
rolls off linearly in dB to a floor. Neither is the catalogue's sinc^2 nor the tuning half's Gaussian; the seabed's
elevation is worked out here with a small-angle formula of our own."""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.optimize import brentq

from sonar_realism.diagnose.heldout.base import Param, held_out
from sonar_realism.frames import SonarImage

DEFAULT_ALTITUDE_M = 2.0
DEFAULT_TILT_DEG = 10.0


def seabed_elevation_deg(frame: SonarImage) -> np.ndarray:
    """Elevation (deg, + up, from the acoustic axis) of a flat seabed per (range, beam): the axis points down by
    the tilt, the seabed at slant range r lies asin(h / r) below the horizontal; off boresight the tilt shows as
    tilt * cos(bearing). Out of reach (r < h): -90."""
    altitude = float(frame.meta.get("sonar_altitude_m", DEFAULT_ALTITUDE_M))
    tilt = math.degrees(float(frame.meta.get("sonar_tilt_rad", math.radians(DEFAULT_TILT_DEG))))
    r = np.maximum(frame.ranges_m, 1e-6)[:, None]
    below = np.degrees(np.arcsin(np.clip(altitude / r, 0.0, 1.0)))
    phi = tilt * np.cos(frame.azimuths_rad)[None, :] - below
    return np.where(r >= altitude, phi, -90.0)


def _hann_amplitude(u: np.ndarray) -> np.ndarray:
    """One-way amplitude pattern of a Hann-shaded aperture, u in units of wavelength / aperture (1 at u = 0)."""
    u = np.asarray(u, dtype=np.float64)
    near_pole = np.abs(np.abs(u) - 1.0) < 1e-6
    safe = np.where(near_pole, 0.0, u)
    value = np.sinc(safe) / (1.0 - safe * safe)
    return np.where(near_pole, 0.5, value)


@functools.lru_cache(maxsize=1)
def _hann_half_power_u() -> float:
    return float(brentq(lambda u: float(_hann_amplitude(np.array(u))) ** 2 - 0.5, 0.1, 1.5))


@held_out("elevation_spread", "hann_pointing",
          beamwidth_deg=Param((8.0, 30.0), (4.0, 60.0), "beamwidth_deg"),
          pointing_error_deg=Param((-2.0, 2.0), (-6.0, 6.0)))
def hann_pointing(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                  instrument: np.random.Generator) -> np.ndarray:
    """Two-way vertical pattern of a Hann-shaded aperture (one-way -3 dB full width `beamwidth_deg`, sidelobes
    -31 dB one way), steered `pointing_error_deg` away from where the mounting says: every pixel scaled by the
    pattern at the seabed's elevation."""
    phi = seabed_elevation_deg(frame) - p["pointing_error_deg"]
    u = phi * _hann_half_power_u() / (p["beamwidth_deg"] / 2.0)
    return (x * _hann_amplitude(u) ** 2).astype(np.float32)


@held_out("elevation_spread", "trapezoid_db",
          flat_deg=Param((4.0, 16.0), (1.0, 30.0)),
          slope_db_per_deg=Param((1.0, 4.0), (0.3, 8.0)),
          floor_db=Param((-38.0, -8.0), (-60.0, -3.0), "floor_db"))
def trapezoid_db(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                 instrument: np.random.Generator) -> np.ndarray:
    """A measured-looking two-way pattern: flat over `flat_deg`, then falling `slope_db_per_deg` per degree
    (amplitude dB) until it meets `floor_db`."""
    beyond = np.maximum(np.abs(seabed_elevation_deg(frame)) - p["flat_deg"] / 2.0, 0.0)
    gain_db = np.maximum(-p["slope_db_per_deg"] * beyond, p["floor_db"])
    return (x * 10 ** (gain_db / 20.0)).astype(np.float32)
