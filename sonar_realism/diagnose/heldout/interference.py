"""Held-out interference: a long foreign pulse of Rayleigh-fading strength added as a random-phase phasor, and
electrical interference as a comb of thin constant-range lines that creeps from ping to ping. Neither is the
catalogue's Poisson arcs (Gaussian pulse, Gaussian bearing lobe) nor the tuning half's drifting rectangular arcs."""

from __future__ import annotations

import math

import numpy as np

from sonar_realism.diagnose.heldout.base import Param, held_out
from sonar_realism.frames import SonarImage


@held_out("interference", "long_pulse_fading",
          probability=Param((0.3, 0.9), (0.1, 1.0)),
          amplitude=Param((0.3, 0.9), (0.1, 2.0), "amplitude"),
          pulse_m=Param((0.1, 0.5), (0.05, 1.5), "thickness_m"),
          floor_db=Param((-30.0, -10.0), (-50.0, -3.0), "floor_db"),
          lobe_deg=Param((3.0, 15.0), (1.0, 40.0)))
def long_pulse_fading(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                      instrument: np.random.Generator) -> np.ndarray:
    """With probability `probability` per ping (at most one), another sonar's long pulse (`pulse_m` of apparent
    range, raised-cosine ends) arrives at a random range from a random bearing: a two-sided exponential lobe of
    `lobe_deg` over a flat `floor_db`; its strength fades (Rayleigh, mean `amplitude`) and it adds to the echoes
    as a phasor of random phase."""
    if ping.random() >= p["probability"]:
        return x.astype(np.float32)
    r = frame.ranges_m
    start = ping.uniform(r[0], r[-1])
    source = ping.uniform(frame.azimuths_rad[0], frame.azimuths_rad[-1])
    position = (r - start) / max(p["pulse_m"], 1e-6)
    along = np.where((position >= 0) & (position <= 1), np.sin(np.pi * np.clip(position, 0, 1)) ** 0.5, 0.0)
    lobe = np.exp(-np.abs(np.degrees(frame.azimuths_rad - source)) / p["lobe_deg"])
    across = np.sqrt(10 ** (p["floor_db"] / 10) + (1 - 10 ** (p["floor_db"] / 10)) * lobe ** 2)
    strength = p["amplitude"] * ping.rayleigh(math.sqrt(2.0 / math.pi))  # Rayleigh of mean 1, times amplitude
    pulse = strength * along[:, None] * across[None, :]
    phase = ping.uniform(0.0, 2.0 * math.pi, x.shape)
    return np.abs(x + pulse * np.exp(1j * phase)).astype(np.float32)


@held_out("interference", "clock_lines",
          amplitude=Param((0.2, 0.6), (0.05, 1.2), "amplitude"),
          spacing_m=Param((0.5, 3.0), (0.2, 6.0)),
          probability=Param((0.3, 1.0), (0.1, 1.0)),
          drift_fraction=Param((0.05, 0.3), (0.0, 0.5)))
def clock_lines(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                instrument: np.random.Generator) -> np.ndarray:
    """Electrical pickup from a clock: on a `probability` share of pings, one-bin lines across every beam,
    `spacing_m` apart in apparent range, whose phase creeps `drift_fraction` of a spacing per ping (the beat
    between the clock and the ping rate). Adds power."""
    if ping.random() >= p["probability"]:
        return x.astype(np.float32)
    r = frame.ranges_m
    offset = (frame.seq * p["drift_fraction"] * p["spacing_m"]) % p["spacing_m"]
    lines = np.arange(r[0] + offset, r[-1], p["spacing_m"])
    rows = np.unique(np.searchsorted(r, lines).clip(0, r.size - 1))
    power = (x * x).astype(np.float64)
    power[rows] += p["amplitude"] ** 2
    return np.sqrt(power).astype(np.float32)
