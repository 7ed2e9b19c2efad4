"""Held-out speckle: an empirical Weibull marginal by a Gaussian copula, and partially developed (Rician) speckle
under a log-normal texture. Neither forms a complex Gaussian field through a Gaussian cell filter (the catalogue)
nor sums discrete scatterers (the tuning half)."""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import gamma as gamma_function
from scipy.special import ndtr

from sonar_realism.diagnose.heldout.base import Param, ar1, held_out
from sonar_realism.frames import SonarImage


def _bartlett(half_width: float) -> np.ndarray:
    """A triangular kernel of half-width `half_width` samples, scaled so it keeps unit variance of white noise."""
    n = max(int(math.ceil(half_width)), 1)
    taps = np.maximum(1.0 - np.abs(np.arange(-n, n + 1)) / max(half_width, 1e-6), 0.0)
    taps = taps if taps.sum() > 0 else np.ones(1)
    return (taps / math.sqrt(float((taps ** 2).sum()))).astype(np.float32)


@held_out("speckle", "weibull_copula",
          weibull_k=Param((1.3, 2.5), (0.7, 4.0)),
          # a triangle of half-width h has the variance of a Gaussian of sigma h / sqrt(6): grain = h / sqrt(6)
          grain_beams=Param((0.6, 3.0), (0.2, 6.0), "grain_beams"),
          grain_ranges=Param((0.4, 2.0), (0.2, 6.0), "grain_ranges"))
def weibull_copula(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                   instrument: np.random.Generator) -> np.ndarray:
    """Weibull amplitude (shape k; k = 2 is Rayleigh, k < 2 heavy tailed) with the grain of a triangular
    correlation kernel: correlated Gaussian noise mapped through its CDF onto the Weibull quantile function.
    Multiplicative, unit mean power."""
    z = ping.standard_normal(x.shape).astype(np.float32)
    kb = _bartlett(math.sqrt(6.0) * p["grain_beams"])
    kr = _bartlett(math.sqrt(6.0) * p["grain_ranges"])
    z = cv2.sepFilter2D(z, -1, kb, kr, borderType=cv2.BORDER_REFLECT_101)
    u = np.clip(ndtr(z.astype(np.float64)), 1e-12, 1.0 - 1e-12)
    k = p["weibull_k"]
    amplitude = (-np.log1p(-u)) ** (1.0 / k)
    return (x * amplitude / math.sqrt(float(gamma_function(1.0 + 2.0 / k)))).astype(np.float32)


@held_out("speckle", "rician_lognormal", strength="diffuse_fraction",
          diffuse_fraction=Param((0.4, 1.0), (0.05, 1.0)),
          texture_sigma=Param((0.0, 0.5), (0.0, 1.2)),
          correlation_beams=Param((0.3, 0.8), (0.0, 0.95)),
          correlation_ranges=Param((0.0, 0.5), (0.0, 0.9)))
def rician_lognormal(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                     instrument: np.random.Generator) -> np.ndarray:
    """Partially developed speckle: a steady (specular) phasor of power 1 - d plus a diffuse circular Gaussian
    phasor of power d, correlated by first-order autoregression across beams and along range, times a log-normal
    texture (unit mean power). d = 1 is Rayleigh; small d leaves the image nearly untouched."""
    d = p["diffuse_fraction"]
    re, im = (ar1(ar1(ping.standard_normal(x.shape), p["correlation_beams"], 1), p["correlation_ranges"], 0)
              for _ in range(2))
    field_power = (math.sqrt(1.0 - d) + math.sqrt(d / 2.0) * re) ** 2 + (d / 2.0) * im ** 2
    s = p["texture_sigma"]
    texture = np.exp(s * ping.standard_normal(x.shape) - s * s / 2.0)
    return (x * np.sqrt(field_power * texture)).astype(np.float32)
