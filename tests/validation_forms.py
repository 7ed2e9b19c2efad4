"""What the tests of the blind validation sets (diagnose/blind_forms.py, diagnose/second_blind_forms.py) share:
small synthetic frames, one form's application, and the contract every form keeps (registry, draws, output,
place)."""

from __future__ import annotations

import math

import numpy as np

from sonar_realism.diagnose.heldout import UNCATALOGUED, apply_held_out
from sonar_realism.diagnose.heldout.base import Implementation
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import EFFECTS

FAMILIES = ("elevation_spread", "multipath", "speckle", "motion_blur", "beam_sidelobes", "range_blur", "tvg_noise",
            "interference", "ring_down", "gamma_quantization")
META = {"sonar_altitude_m": 1.5, "sonar_tilt_rad": math.radians(10.0)}


def make_frame(intensity: np.ndarray | None = None, n_ranges: int = 400, n_beams: int = 128, step: float = 0.02,
               seq: int = 0, meta: dict | None = None) -> SonarImage:
    """Sine-spaced beams over 130 degrees, `step` m bins from 0.3 m; by default a dark water column over a
    textured seabed from 3 m with one bright target."""
    if intensity is not None:
        n_ranges, n_beams = intensity.shape
    ranges = 0.3 + step * np.arange(n_ranges)
    limit = math.sin(math.radians(65.0))
    azimuths = np.arcsin(np.linspace(-limit, limit, n_beams))
    if intensity is None:
        rng = np.random.default_rng(42)
        intensity = np.zeros((n_ranges, n_beams), np.float32)
        seabed = ranges >= 3.0
        intensity[seabed] = 0.25 * rng.gamma(4.0, 0.25, (int(seabed.sum()), n_beams))
        intensity[n_ranges * 3 // 4, n_beams // 3] = 0.95
        intensity = np.clip(intensity, 0.0, 1.0).astype(np.float32)
    return SonarImage(intensity.astype(np.float32), ranges, azimuths, seq=seq, frame_id="sonar", stamp_ns=0,
                      intensity_scale=1.0, meta=dict(META) if meta is None else meta)


def flat_frame(level: float = 0.3, n_ranges: int = 400, n_beams: int = 128, **kwargs) -> SonarImage:
    return make_frame(np.full((n_ranges, n_beams), level, np.float32), **kwargs)


def point_frame(row: int, col: int, value: float = 0.8, n_ranges: int = 400, n_beams: int = 128,
                **kwargs) -> SonarImage:
    image = np.zeros((n_ranges, n_beams), np.float32)
    image[row, col] = value
    return make_frame(image, **kwargs)


def apply_form(entry: Implementation, frame: SonarImage, p: dict[str, float], ping: int = 1,
               instrument: int = 2) -> np.ndarray:
    return entry.apply(frame.normalized(), frame, p, np.random.default_rng(ping), np.random.default_rng(instrument))


def as_amplitude(y: np.ndarray) -> np.ndarray:
    return y.astype(np.float64) / 255.0 if y.dtype == np.uint8 else y.astype(np.float64)


def check_output_contract(entry: Implementation) -> None:
    """Shape, dtype, finite and non-negative, deterministic for fixed draws, a visible change, and `apply_held_out`
    marks the frames it made."""
    frame = make_frame()
    x = frame.normalized()
    draws = [entry.draw("inside", np.random.default_rng(seed)) for seed in (0, 1)]
    draws.append(entry.draw("wide", np.random.default_rng(5)))
    for p in draws:
        y = apply_form(entry, frame, p)
        assert y.shape == x.shape
        assert y.dtype == (np.uint8 if entry.family == "gamma_quantization" else np.float32)
        assert np.all(np.isfinite(y)) and np.all(y >= 0)
        np.testing.assert_array_equal(y, apply_form(entry, frame, p))
    changed = np.abs(as_amplitude(apply_form(entry, frame, draws[0])) - x)
    assert changed.max() > 0.02
    frames = apply_held_out([make_frame(seq=0), make_frame(seq=1)], entry.name, draws[0], seed=9)
    assert len(frames) == 2 and frames[0].meta["held_out"] == entry.name


def place_covers(frame: SonarImage, changed: np.ndarray, range_m: tuple[tuple[float, float], ...],
                 bearing_deg: tuple[tuple[float, float], ...]) -> bool:
    """Whether every changed cell lies in one of the range intervals and one of the bearing intervals."""
    rows, cols = np.nonzero(changed)
    ranges, bearings = frame.ranges_m[rows], np.degrees(frame.azimuths_rad)[cols]
    in_range = np.zeros(rows.size, bool)
    for lo, hi in range_m:
        in_range |= (ranges >= lo - 1e-9) & (ranges <= hi + 1e-9)
    in_bearing = np.zeros(cols.size, bool)
    for lo, hi in bearing_deg:
        in_bearing |= (bearings >= lo - 1e-9) & (bearings <= hi + 1e-9)
    return bool(in_range.all() and in_bearing.all())


def check_registry(registry: dict[str, Implementation]) -> None:
    """One form per catalogued family, two un-catalogued effects, each named `family/form`."""
    families = [entry.family for entry in registry.values()]
    assert sorted(f for f in families if f != UNCATALOGUED) == sorted(FAMILIES)
    assert families.count(UNCATALOGUED) == 2
    assert all(name == f"{entry.family}/{entry.form}" for name, entry in registry.items())


def check_draw_ranges(entry: Implementation) -> None:
    """Wide draws contain the inside ones, catalogued parameters' inside draws stay inside the catalogue's bounds,
    and only un-catalogued effects have a place."""
    assert entry.description and entry.strength in entry.params
    assert (entry.place is not None) == (entry.family == UNCATALOGUED)
    bounds = {} if entry.family == UNCATALOGUED else EFFECTS[entry.family].PARAM_BOUNDS
    for key, param in entry.params.items():
        assert param.wide[0] < param.inside[0] <= param.inside[1] < param.wide[1], key
        if param.catalogue:
            assert entry.family != UNCATALOGUED
            lo, hi = bounds[param.catalogue]
            assert lo <= param.inside[0] and param.inside[1] <= hi, key
