"""Effects the catalogue has no stage for. The right diagnosis is "unexplained, at these places"; a catalogued
effect selected for one of them is a wrong answer. (The tuning half withholds a Gaussian lens band and a smooth
vignetting ripple; these are other patterns.)"""

from __future__ import annotations

import math

import numpy as np

from sonar_realism.diagnose.heldout.base import UNCATALOGUED, Param, Place, held_out
from sonar_realism.frames import SonarImage


def _bad_beams(frame: SonarImage, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Which beams have a channel gain error, and its gain (dB): fixed by `layout_seed`, not per ping."""
    layout = np.random.default_rng(int(p["layout_seed"]))
    count = int(p["bad_beams"])
    beams = np.sort(layout.choice(frame.n_beams, size=min(count, frame.n_beams), replace=False))
    gains_db = p["depth_db"] * layout.choice([-1.0, 1.0], size=beams.size, p=[0.7, 0.3])
    return beams, gains_db


def _stripe_place(frame: SonarImage, p: dict[str, float]) -> Place:
    beams, _ = _bad_beams(frame, p)
    bearings = np.degrees(frame.azimuths_rad[beams])
    return Place(bearing_deg=tuple((float(b), float(b)) for b in bearings))


@held_out(UNCATALOGUED, "column_stripes", place=_stripe_place,
          bad_beams=Param((3.0, 6.0), (1.0, 12.0), integer=True),
          depth_db=Param((3.0, 6.0), (1.5, 10.0)),
          layout_seed=Param((0.0, 1e6), (0.0, 1e6), integer=True))
def column_stripes(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                   instrument: np.random.Generator) -> np.ndarray:
    """A few receive channels with a wrong gain (mostly low: a failing element), fixed over the recording: thin
    dark or bright columns at the same beams in every frame."""
    beams, gains_db = _bad_beams(frame, p)
    gain = np.ones(frame.n_beams)
    gain[beams] = 10 ** (gains_db / 20.0)
    return (x * gain[None, :]).astype(np.float32)


def _band_place(frame: SonarImage, p: dict[str, float]) -> Place:
    r = frame.ranges_m
    start = r[0] + p["at_fraction"] * (r[-1] - r[0])
    return Place(range_m=((float(start), float(start + p["width_m"])),))


@held_out(UNCATALOGUED, "housing_band", place=_band_place,
          at_fraction=Param((0.3, 0.8), (0.15, 0.9)),
          width_m=Param((0.05, 0.2), (0.02, 0.5)),
          amplitude=Param((0.2, 0.5), (0.1, 1.0)))
def housing_band(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                 instrument: np.random.Generator) -> np.ndarray:
    """A reflection inside the housing arrives at the same delay every ping: a flat-topped band of `width_m`
    starting at `at_fraction` of the range span, strongest at boresight (cos^2 of the bearing), added in power."""
    r = frame.ranges_m
    start = r[0] + p["at_fraction"] * (r[-1] - r[0])
    along = ((r >= start) & (r <= start + p["width_m"])).astype(np.float64)
    if not along.any():
        along[int(np.argmin(np.abs(r - start)))] = 1.0
    across = np.cos(frame.azimuths_rad) ** 2
    band = p["amplitude"] * along[:, None] * across[None, :]
    return np.sqrt(x * x + band * band).astype(np.float32)


def _edges_place(frame: SonarImage, p: dict[str, float]) -> Place:
    theta = np.degrees(frame.azimuths_rad)
    span = theta[-1] - theta[0]
    return Place(bearing_deg=((float(theta[0]), float(theta[0] + 0.2 * span)),
                              (float(theta[-1] - 0.2 * span), float(theta[-1]))))


@held_out(UNCATALOGUED, "fan_gain_drift", place=_edges_place,
          tilt_db=Param((3.0, 6.0), (1.5, 10.0)),
          bow_db=Param((-2.0, 2.0), (-4.0, 4.0)))
def fan_gain_drift(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                   instrument: np.random.Generator) -> np.ndarray:
    """A slow gain drift across the fan: `tilt_db` from the port edge to the starboard edge (linear in dB) plus a
    `bow_db` bow (the fan's centre against its edges), the same in every frame."""
    u = np.linspace(-1.0, 1.0, frame.n_beams)
    gain_db = p["tilt_db"] * u / 2.0 + p["bow_db"] * (1.0 - u * u)
    return (x * 10 ** (gain_db / 20.0)[None, :]).astype(np.float32)


def _notch_place(frame: SonarImage, p: dict[str, float]) -> Place:
    r = frame.ranges_m
    start = r[0] + p["at_fraction"] * (r[-1] - r[0])
    return Place(range_m=((float(start), float(start + p["width_m"])),))


@held_out(UNCATALOGUED, "range_gain_notch", place=_notch_place,
          at_fraction=Param((0.3, 0.8), (0.15, 0.9)),
          width_m=Param((0.2, 0.8), (0.1, 1.5)),
          depth_db=Param((3.0, 8.0), (1.5, 15.0)))
def range_gain_notch(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                     instrument: np.random.Generator) -> np.ndarray:
    """A glitch in the TVG table: over `width_m` starting at `at_fraction` of the span the gain sags by
    `depth_db` (raised-cosine shaped), in every frame."""
    r = frame.ranges_m
    start = r[0] + p["at_fraction"] * (r[-1] - r[0])
    inside = np.clip((r - start) / max(p["width_m"], 1e-6), 0.0, 1.0)
    sag_db = np.where((r >= start) & (r <= start + p["width_m"]),
                      p["depth_db"] * 0.5 * (1.0 - np.cos(2.0 * math.pi * inside)), 0.0)
    return (x * 10 ** (-sag_db / 20.0)[:, None]).astype(np.float32)
