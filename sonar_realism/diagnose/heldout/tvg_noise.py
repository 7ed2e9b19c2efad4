"""Held-out receiver noise and TVG: noise power added to echo power under a power-law TVG with a power-law gain
error, and real (one-quadrature) noise under a switched, stepwise TVG. Neither adds complex noise as a phasor
under a log-plus-absorption law with a linear-in-dB ramp (the catalogue), nor applies the losses and TVG around a
beam-averaged complex noise (the tuning half)."""

from __future__ import annotations

import numpy as np

from sonar_realism.diagnose.heldout.base import Param, ar1, held_out
from sonar_realism.frames import SonarImage


def _relative_range(frame: SonarImage) -> np.ndarray:
    r = np.maximum(frame.ranges_m, 1e-3)
    return r / r[-1]


@held_out("tvg_noise", "incoherent_power_law", strength="noise_amplitude",
          noise_amplitude=Param((0.05, 0.4), (0.02, 0.8), "noise_amplitude"),
          tvg_log_coeff_db=Param((15.0, 40.0), (5.0, 60.0), "tvg_log_coeff_db"),
          mismatch_db_per_decade=Param((-6.0, 6.0), (-15.0, 15.0)),
          correlation_ranges=Param((0.0, 0.7), (0.0, 0.9)))
def incoherent_power_law(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                         instrument: np.random.Generator) -> np.ndarray:
    """Echo power and noise power add (no phasor sum). The TVG is a pure power law r^(n/20) in amplitude, so the
    noise it amplifies grows as that law up to `noise_amplitude` (rms) at the last bin; the receiver's bandwidth
    correlates the noise along range (first-order autoregression). A TVG set off by
    `mismatch_db_per_decade` leaves a power-law gain error on the echoes."""
    rel = _relative_range(frame)[:, None]
    noise_rms = p["noise_amplitude"] * rel ** (p["tvg_log_coeff_db"] / 20.0)
    re, im = (ar1(ping.standard_normal(x.shape), p["correlation_ranges"], 0) for _ in range(2))
    noise_power = noise_rms ** 2 * (re * re + im * im) / 2.0
    r = np.maximum(frame.ranges_m, 1e-3)[:, None]
    gain = (r / float(np.median(r))) ** (p["mismatch_db_per_decade"] / 20.0)
    return np.sqrt((x * gain) ** 2 + noise_power).astype(np.float32)


@held_out("tvg_noise", "stepped_real_noise",
          noise_amplitude=Param((0.05, 0.4), (0.02, 0.8), "noise_amplitude"),
          slope_db=Param((15.0, 40.0), (5.0, 60.0), "tvg_log_coeff_db"),
          step_db=Param((3.0, 6.0), (1.0, 12.0)))
def stepped_real_noise(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                       instrument: np.random.Generator) -> np.ndarray:
    """A switched-gain receiver: the TVG rises in steps of `step_db` (following slope_db * log10 r on average),
    so the amplified noise floor is a staircase in range; the noise is one quadrature only (real Gaussian added
    to the amplitude, so a dark pixel is half-normal, not Rayleigh)."""
    rel = _relative_range(frame)
    gain_db = p["slope_db"] * np.log10(rel)  # <= 0, 0 at the last bin
    stepped_db = np.floor(gain_db / p["step_db"]) * p["step_db"]
    noise_rms = p["noise_amplitude"] * 10 ** (stepped_db / 20.0)
    noise = ping.standard_normal(x.shape) * noise_rms[:, None]
    return np.abs(x + noise).astype(np.float32)
