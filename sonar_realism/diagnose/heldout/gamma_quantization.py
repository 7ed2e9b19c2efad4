"""Held-out output mappings: logarithmic compression to 8 bits over a dynamic range, and a knee compressor read
by a coarse ADC (few levels, truncated). Neither is the catalogue's rounded power law nor the tuning half's
dithered 12-bit ADC under a gamma table."""

from __future__ import annotations

import numpy as np

from sonar_realism.diagnose.heldout.base import Param, held_out
from sonar_realism.frames import SonarImage


@held_out("gamma_quantization", "log_8bit",
          gain=Param((0.5, 3.0), (0.1, 10.0), "gain"),
          dynamic_range_db=Param((30.0, 60.0), (20.0, 90.0)))
def log_8bit(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
             instrument: np.random.Generator) -> np.ndarray:
    """A log-output sonar: 0 counts at `dynamic_range_db` below full scale, 255 at full scale (gain * A = 1),
    linear in dB between, rounded and clipped."""
    level_db = 20.0 * np.log10(np.maximum(p["gain"] * x, 1e-12))
    counts = 255.0 * (1.0 + level_db / p["dynamic_range_db"])
    return np.clip(np.round(counts), 0, 255).astype(np.uint8)


@held_out("gamma_quantization", "knee_coarse_adc",
          gain=Param((0.8, 3.0), (0.3, 8.0), "gain"),
          bits=Param((5.0, 7.0), (3.0, 8.0), integer=True),
          knee=Param((0.1, 0.4), (0.05, 0.8)),
          slope=Param((0.1, 0.5), (0.02, 1.0)))
def knee_coarse_adc(x: np.ndarray, frame: SonarImage, p: dict[str, float], ping: np.random.Generator,
                    instrument: np.random.Generator) -> np.ndarray:
    """A piecewise-linear compressor (unit slope up to `knee`, `slope` above, clipped at 1) read by a `bits`-bit
    ADC that truncates, spread over 0..255."""
    y = p["gain"] * x
    compressed = np.where(y <= p["knee"], y, p["knee"] + p["slope"] * (y - p["knee"]))
    top = p["knee"] + p["slope"] * (1.0 - p["knee"])  # the compressor's output at y = 1 (full scale)
    levels = 2 ** int(p["bits"])
    code = np.floor(np.clip(compressed / max(top, 1e-6), 0.0, 1.0) * (levels - 1))
    return np.clip(np.round(code * 255.0 / (levels - 1)), 0, 255).astype(np.uint8)
