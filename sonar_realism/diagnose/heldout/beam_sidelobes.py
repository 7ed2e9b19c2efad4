"""Held-out horizontal beam patterns: a Dolph-Chebyshev array applied coherently to amplitude, and a Gaussian
mainlobe with an exponential skirt and grating lobes applied to power. Neither is the catalogue's rescaled sinc^2
with a flat floor nor the tuning half's shaded-array power pattern with element errors."""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.signal.windows import chebwin

from sonar_realism.diagnose.heldout.base import Param, fft_convolve, held_out, sin_step
from sonar_realism.frames import SonarImage

ELEMENTS = 48
OVERSAMPLE = 32


def _chebyshev_pattern(sidelobe_db: float, mainlobe_deg: float, offsets: np.ndarray) -> np.ndarray:
    """Real (signed) one-way amplitude pattern of a Dolph-Chebyshev-shaded array: every sidelobe at `sidelobe_db`
    (power, below the peak), -3 dB full width `mainlobe_deg`, sampled at sin-offsets `offsets`."""
    with warnings.catch_warnings():  # scipy warns that weak Chebyshev shading is poor for spectral analysis
        warnings.simplefilter("ignore", UserWarning)
        weights = chebwin(ELEMENTS, at=-sidelobe_db)
    n = ELEMENTS * OVERSAMPLE
    # the array is symmetric, so its pattern is real once the phase ramp of the element positions is removed
    frequency = np.fft.fftfreq(n) * n
    field = np.fft.fftshift(np.fft.fft(weights, n) * np.exp(1j * np.pi * frequency * (ELEMENTS - 1) / n))
    pattern = field.real / field.real.max()
    u = (np.arange(n) - n // 2) / OVERSAMPLE
    half_width = float(u[(u >= 0) & (pattern ** 2 >= 0.5)].max())
    scale = math.sin(math.radians(mainlobe_deg)) / 2.0 / half_width
    inside = np.abs(offsets) <= u[-1] * scale
    return np.where(inside, np.interp(offsets, u * scale, pattern), 0.0)


@held_out("beam_sidelobes", "chebyshev_coherent", strength="sidelobe_db",
          sidelobe_db=Param((-40.0, -13.0), (-50.0, -8.0), "sidelobe_db"),
          mainlobe_deg=Param((0.4, 2.5), (0.15, 4.0), "mainlobe_deg"))
def chebyshev_coherent(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                       instrument: np.random.Generator) -> np.ndarray:
    """Beamforming as a coherent sum: each row's amplitude (all returns in phase) convolved with the signed
    equal-ripple pattern of a Chebyshev-shaded line array, then detected. A uniform row keeps its level; a bright
    point gets sidelobes at `sidelobe_db` all across the fan."""
    offsets = np.arange(-(frame.n_beams - 1), frame.n_beams) * sin_step(frame)
    kernel = _chebyshev_pattern(p["sidelobe_db"], p["mainlobe_deg"], offsets)
    summed = fft_convolve(x.astype(np.float64), kernel, 1, frame.n_beams - 1)
    # the signed sidelobes never die out, so each beam is normalised by the part of the pattern inside the fan:
    # a uniform row stays uniform up to its edges
    covered = fft_convolve(np.ones((1, frame.n_beams)), kernel, 1, frame.n_beams - 1)
    return np.abs(summed / covered).astype(np.float32)


@held_out("beam_sidelobes", "gaussian_skirt_grating",
          mainlobe_deg=Param((0.4, 2.5), (0.15, 4.0), "mainlobe_deg"),
          skirt_db=Param((-35.0, -15.0), (-50.0, -6.0), "sidelobe_db"),
          skirt_decay_deg=Param((1.0, 8.0), (0.5, 20.0)),
          grating_db=Param((-40.0, -22.0), (-45.0, -12.0)),
          grating_offset_deg=Param((10.0, 40.0), (5.0, 60.0)))
def gaussian_skirt_grating(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                           instrument: np.random.Generator) -> np.ndarray:
    """Power pattern of a measured transducer: a Gaussian mainlobe, a two-sided exponential skirt `skirt_db`
    below the peak decaying over `skirt_decay_deg`, and a pair of grating lobes (element pitch above half a
    wavelength) `grating_db` down at +-`grating_offset_deg`. Rows mix in power."""
    offsets = np.arange(-(frame.n_beams - 1), frame.n_beams) * sin_step(frame)
    sigma = math.sin(math.radians(p["mainlobe_deg"])) / 2.3548
    main = np.exp(-0.5 * (offsets / sigma) ** 2)
    skirt = 10 ** (p["skirt_db"] / 10) * np.exp(-np.abs(offsets) / math.sin(math.radians(p["skirt_decay_deg"])))
    skirt = np.where(np.abs(offsets) > 1.5 * sigma, skirt, 0.0)
    grating_u = math.sin(math.radians(p["grating_offset_deg"]))
    grating = 10 ** (p["grating_db"] / 10) * sum(np.exp(-0.5 * ((offsets - s) / sigma) ** 2)
                                                  for s in (-grating_u, grating_u))
    kernel = main + skirt + grating
    kernel /= kernel.sum()
    power = fft_convolve((x * x).astype(np.float64), kernel, 1, frame.n_beams - 1)
    return np.sqrt(np.maximum(power, 0.0)).astype(np.float32)
