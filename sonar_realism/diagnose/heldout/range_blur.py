"""Held-out range point-spread functions: a causal CW pulse behind a one-pole receiver (power), and the
triangular matched-filter response of a CW pulse applied coherently to amplitude. Neither is the catalogue's
Gaussian with two Gaussian sidelobes nor the tuning half's |FT(spectral taper)|^2."""

from __future__ import annotations

import numpy as np

from sonar_realism.diagnose.heldout.base import Param, bin_m, fft_convolve, held_out
from sonar_realism.frames import SonarImage


@held_out("range_blur", "rect_rc_causal",
          pulse_m=Param((0.01, 0.2), (0.001, 0.5), "resolution_m"),
          tail_m=Param((0.005, 0.08), (0.0, 0.3)))
def rect_rc_causal(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                   instrument: np.random.Generator) -> np.ndarray:
    """A CW pulse of length `pulse_m` (c tau / 2) seen through a one-pole receiver of time constant `tail_m`
    (in metres of range): the power PSF is a box followed by an exponential tail, and it is causal, so echoes
    spread only to longer ranges."""
    step = bin_m(frame)
    offsets = np.arange(0, int(np.ceil((p["pulse_m"] + 6 * p["tail_m"]) / step)) + 2) * step
    box = (offsets < max(p["pulse_m"], step)).astype(np.float64)
    if p["tail_m"] > 0:
        tail = np.exp(-offsets / p["tail_m"])
        kernel = np.convolve(box, tail / tail.sum())[: offsets.size]
    else:
        kernel = box
    kernel /= kernel.sum()
    power = fft_convolve((x * x).astype(np.float64), kernel, 0, 0)
    return np.sqrt(np.maximum(power, 0.0)).astype(np.float32)


@held_out("range_blur", "triangle_coherent",
          resolution_m=Param((0.02, 0.25), (0.004, 0.6), "resolution_m"))
def triangle_coherent(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                      instrument: np.random.Generator) -> np.ndarray:
    """The matched filter of a CW pulse: a triangle of half-width `resolution_m` in amplitude, summed coherently
    (returns in phase) along range, then detected."""
    step = bin_m(frame)
    half = max(p["resolution_m"] / step, 1.0)
    n = int(np.ceil(half))
    kernel = np.maximum(1.0 - np.abs(np.arange(-n, n + 1)) / half, 0.0)
    kernel /= kernel.sum()
    return np.abs(fft_convolve(x.astype(np.float64), kernel, 0, n)).astype(np.float32)
