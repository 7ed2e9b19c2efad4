"""The simulated sensor: an Oculus M1200d-class forward-looking sonar and its polar output grid."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import uniform_ranges

SOUND_SPEED_MPS = 1500.0


@dataclass(frozen=True)
class SensorConfig:
    """Geometry and acoustics of the simulated sonar.

    frequency_hz:        carrier (1.2 MHz wide mode, 2.1 MHz narrow mode of an M1200d).
    n_beams, n_ranges:   output grid (beams equally spaced in sin(bearing), like the real bearing table).
    fov_deg:             horizontal field of view (130 deg at 1.2 MHz, 60 deg at 2.1 MHz).
    vertical_fov_deg:    vertical aperture that the ray caster integrates over (20 / 12 deg).
    beam_resolution_deg: -3 dB horizontal beam width (0.6 / 0.4 deg), recorded in meta for the effects.
    min_range_m, max_range_m: first and last range-bin edges.
    elevation_rays:      rays per beam across the vertical aperture for object hits (the seabed is solved per
                         pixel and needs none).
    """

    frequency_hz: float = 1.2e6
    n_beams: int = 256
    n_ranges: int = 512
    fov_deg: float = 130.0
    vertical_fov_deg: float = 20.0
    beam_resolution_deg: float = 0.6
    min_range_m: float = 0.3
    max_range_m: float = 15.0
    sound_speed_mps: float = SOUND_SPEED_MPS
    elevation_rays: int = 96

    def validate(self) -> None:
        checks = [
            (0.1e6 <= self.frequency_hz <= 10e6, f"frequency_hz {self.frequency_hz} not in [0.1 MHz, 10 MHz]"),
            (2 <= self.n_beams <= 4096, f"n_beams {self.n_beams} not in [2, 4096]"),
            (2 <= self.n_ranges <= 16384, f"n_ranges {self.n_ranges} not in [2, 16384]"),
            (1.0 <= self.fov_deg <= 179.0, f"fov_deg {self.fov_deg} not in [1, 179]"),
            (0.5 <= self.vertical_fov_deg <= 90.0, f"vertical_fov_deg {self.vertical_fov_deg} not in [0.5, 90]"),
            (0.01 <= self.beam_resolution_deg <= 30.0, f"beam_resolution_deg {self.beam_resolution_deg} not in "
                                                       "[0.01, 30]"),
            (0.0 <= self.min_range_m < self.max_range_m, f"need 0 <= min_range_m ({self.min_range_m}) < "
                                                         f"max_range_m ({self.max_range_m})"),
            (self.max_range_m <= 500.0, f"max_range_m {self.max_range_m} beyond 500 m"),
            (1300.0 <= self.sound_speed_mps <= 1700.0, f"sound_speed_mps {self.sound_speed_mps} not in [1300, 1700]"),
            (4 <= self.elevation_rays <= 2048, f"elevation_rays {self.elevation_rays} not in [4, 2048]"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"sensor: {message}")

    @property
    def ranges_m(self) -> np.ndarray:
        return uniform_ranges(self.n_ranges, self.max_range_m, self.min_range_m)

    @property
    def azimuths_rad(self) -> np.ndarray:
        return oculus_bearing_table(self.n_beams, self.fov_deg)

    @property
    def range_bin_m(self) -> float:
        return (self.max_range_m - self.min_range_m) / self.n_ranges

    @property
    def elevations_rad(self) -> np.ndarray:
        """Centres of the elevation rays across the vertical aperture (+ up)."""
        half = math.radians(self.vertical_fov_deg) / 2
        step = 2 * half / self.elevation_rays
        return -half + (np.arange(self.elevation_rays) + 0.5) * step

    def meta(self) -> dict[str, float]:
        return {"frequency_hz": self.frequency_hz, "sound_speed_mps": self.sound_speed_mps,
                "range_resolution_m": self.range_bin_m, "vertical_aperture_rad": math.radians(self.vertical_fov_deg),
                "beam_resolution_rad": math.radians(self.beam_resolution_deg)}


def oculus_bearing_table(n_beams: int, fov_deg: float) -> np.ndarray:
    """An Oculus-like bearing table: beams equally spaced in sin(bearing), stored in hundredths of a degree.

    The real table (e.g. tests/data/three_pings_8bit.raw) is int16 in 0.01 deg with equal steps in sin, so its
    steps alternate between neighbouring hundredths (25/26 there) and widen towards the edges as 1/cos.
    """
    half = math.radians(fov_deg) / 2
    sines = np.linspace(-math.sin(half), math.sin(half), n_beams)
    exact = np.degrees(np.arcsin(sines))
    centi_degrees = np.rint(exact * 100.0)
    if n_beams > 1 and not (np.diff(centi_degrees) > 0).all():
        return np.radians(exact)  # beams closer than 0.01 deg: the int16 table cannot hold them, keep exact
    return np.radians(centi_degrees / 100.0)


# The two operating modes of an Oculus M1200d (datasheet geometry; range chosen to suit a seabed survey).
M1200D_1200KHZ = SensorConfig()
M1200D_2100KHZ = SensorConfig(frequency_hz=2.1e6, fov_deg=60.0, vertical_fov_deg=12.0, beam_resolution_deg=0.4,
                              min_range_m=0.1, max_range_m=6.0)
SENSORS = {"m1200d_1200khz": M1200D_1200KHZ, "m1200d_2100khz": M1200D_2100KHZ}
