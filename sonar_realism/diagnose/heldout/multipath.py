"""Held-out multipath: a diffuse seabed-bounce ghost added as a random-phase phasor, and a comb of wall echoes
confined to one side of the fan. Neither is the catalogue's sharp power copy at a fixed offset nor the tuning
half's surface image method whose offset shrinks with range."""

from __future__ import annotations

import math

import cv2
import numpy as np

from sonar_realism.diagnose.heldout.base import Param, bin_m, fft_convolve, held_out
from sonar_realism.frames import SonarImage


def _delayed(values: np.ndarray, offset_bins: float) -> np.ndarray:
    """`values` moved `offset_bins` (fractional) to longer range, zeros shifted in."""
    whole = int(math.floor(offset_bins))
    frac = offset_bins - whole
    out = np.zeros_like(values)
    n = values.shape[0]
    for shift, weight in ((whole, 1.0 - frac), (whole + 1, frac)):
        if 0 <= shift < n and weight > 0:
            out[shift:] += weight * values[: n - shift]
    return out


@held_out("multipath", "diffuse_phasor",
          reflection_coeff=Param((0.3, 0.75), (0.15, 0.95), "reflection_coeff"),
          ghost_offset_m=Param((0.5, 4.0), (0.05, 6.0), "ghost_offset_m"),
          tail_m=Param((0.05, 0.4), (0.0, 1.0)),
          spread_beams=Param((0.0, 1.5), (0.0, 4.0)))
def diffuse_phasor(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                   instrument: np.random.Generator) -> np.ndarray:
    """A bounce off a rough seabed: the scene's amplitude, delayed by `ghost_offset_m`, spread to longer range by
    an exponential tail of `tail_m` and across `spread_beams` (Gaussian sigma), added to the direct return as a
    phasor of random phase (the paths' lengths differ by many wavelengths)."""
    step = bin_m(frame)
    ghost = _delayed(x.astype(np.float64), p["ghost_offset_m"] / step)
    if p["tail_m"] > step / 4:
        taps = np.exp(-np.arange(int(math.ceil(6 * p["tail_m"] / step)) + 1) * step / p["tail_m"])
        ghost = fft_convolve(ghost, taps / taps.sum(), 0, 0)
    if p["spread_beams"] > 0.2:
        ghost = cv2.GaussianBlur(ghost, (0, 0), sigmaX=p["spread_beams"], sigmaY=1e-3)
    phase = ping.uniform(0.0, 2.0 * math.pi, x.shape)
    field = x + p["reflection_coeff"] * ghost * np.exp(1j * phase)
    return np.abs(field).astype(np.float32)


@held_out("multipath", "wall_comb_sector",
          reflection_coeff=Param((0.4, 0.8), (0.2, 0.95), "reflection_coeff"),
          spacing_m=Param((0.5, 3.0), (0.05, 6.0), "ghost_offset_m"),
          bounces=Param((2.0, 3.0), (1.0, 4.0), integer=True),
          sector_fraction=Param((0.3, 0.7), (0.15, 1.0)))
def wall_comb_sector(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                     instrument: np.random.Generator) -> np.ndarray:
    """Reverberation between the sonar and a wall on one side: echoes repeat every `spacing_m`, each bounce
    `reflection_coeff` weaker in amplitude and smeared a little more along range, only in the part of the fan
    that faces the wall (`sector_fraction` of it, soft edged, starting at the port edge)."""
    step = bin_m(frame)
    power = (x * x).astype(np.float64)
    out = power.copy()
    across = np.linspace(0.0, 1.0, frame.n_beams)
    sector = 1.0 / (1.0 + np.exp((across - p["sector_fraction"]) / 0.03))
    for k in range(1, int(p["bounces"]) + 1):
        ghost = _delayed(power, k * p["spacing_m"] / step)
        ghost = cv2.GaussianBlur(ghost, (0, 0), sigmaX=1e-3, sigmaY=0.5 * k)
        out += p["reflection_coeff"] ** (2 * k) * ghost * sector[None, :]
    return np.sqrt(out).astype(np.float32)
