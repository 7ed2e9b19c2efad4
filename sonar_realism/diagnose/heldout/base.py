"""The held-out half of the diagnosis' validation: effects written without looking at the catalogue's code.

Each implementation is a plain function `apply(x, frame, p, ping, instrument)`:
- `x` float32 linear amplitude [n_ranges, n_beams] of a clean frame (the simulator's output, ~[0, 1]);
- `p` its drawn parameters; `ping` the per-frame random source; `instrument` a generator that starts from the same
  seed for every frame of a case (properties of the sensor that do not change from ping to ping);
- returns float32 amplitude >= 0, or uint8 counts for an output mapping.

Nobody tunes the diagnosis against these: they were written and committed before the diagnosis ever ran on them.
Each one registers itself with `@held_out(family, form, ...)`, so adding one is adding a function in its family's
file. A second *tuning* set of the same kind (`sonar_realism/diagnose/tuning_forms.py`, `@tuning_form`) lives in
its own registry, `TUNING`: the diagnosis may be tuned against it, and adding to it never changes the held-out
half's draws. A third set (`sonar_realism/diagnose/blind_forms.py`, `@blind_form`, registry `BLIND`) was written
later by other hands that read neither the catalogue's code nor the diagnosis': a fresh held-out measurement
after the first half had been looked at over several rounds. A fourth (`sonar_realism/diagnose/second_blind_forms.py`,
`@second_blind_form`, registry `SECOND_BLIND`) was written blind in the same way after the third had been run: forms
nobody had yet measured the diagnosis on.

`family` is a catalogue effect name, or UNCATALOGUED for effects the catalogue has no stage for
(their right answer is "residual, at these places": `place` says where).

Parameters are drawn in one of two modes, recorded with every case: "inside" keeps every parameter that has a
catalogue counterpart (`Param.catalogue`) inside that parameter's PARAM_BOUNDS (the fit's search range) and the
others at strengths the catalogue's form can plausibly stand in for; "wide" draws from a range that reaches beyond
both.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import EFFECTS

UNCATALOGUED = "uncatalogued"
DrawMode = Literal["inside", "wide"]
Apply = Callable[[np.ndarray, SonarImage, dict[str, float], np.random.Generator, np.random.Generator], np.ndarray]


@dataclass(frozen=True)
class Param:
    """Draw ranges of one parameter. `catalogue`: the catalogue parameter of the same meaning ("" = none);
    `integer`: rounded after the draw."""

    inside: tuple[float, float]
    wide: tuple[float, float]
    catalogue: str = ""
    integer: bool = False

    def draw(self, mode: DrawMode, rng: np.random.Generator) -> float:
        lo, hi = self.inside if mode == "inside" else self.wide
        value = float(rng.uniform(lo, hi))
        return float(round(value)) if self.integer else value


@dataclass(frozen=True)
class Place:
    """Where an un-catalogued effect's residual belongs: range intervals (m) and/or bearing intervals (deg)."""

    range_m: tuple[tuple[float, float], ...] = ()
    bearing_deg: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class Implementation:
    family: str
    form: str
    description: str
    apply: Apply
    params: dict[str, Param]
    place: Callable[[SonarImage, dict[str, float]], Place] | None = None
    strength: str = ""  # the parameter a detection-limit sweep varies ("" = none)

    @property
    def name(self) -> str:
        return f"{self.family}/{self.form}"

    def draw(self, mode: DrawMode, rng: np.random.Generator) -> dict[str, float]:
        return {key: param.draw(mode, rng) for key, param in self.params.items()}

    def outside_bounds(self, params: dict[str, float]) -> list[str]:
        """The drawn parameters that lie outside their catalogue counterpart's PARAM_BOUNDS."""
        if self.family == UNCATALOGUED:
            return []
        bounds = EFFECTS[self.family].PARAM_BOUNDS
        return [key for key, param in self.params.items()
                if param.catalogue and not bounds[param.catalogue][0] <= params[key] <= bounds[param.catalogue][1]]


IMPLEMENTATIONS: dict[str, Implementation] = {}  # the held-out half
TUNING: dict[str, Implementation] = {}  # a second tuning set (beside diagnose/validation.py's alternatives)
BLIND: dict[str, Implementation] = {}  # a third set, written blind to the catalogue's and the diagnosis' code
SECOND_BLIND: dict[str, Implementation] = {}  # a fourth set, written blind like the third, after the third had been run
REGISTRIES = (IMPLEMENTATIONS, TUNING, BLIND, SECOND_BLIND)


def held_out(family: str, form: str, place: Callable[[SonarImage, dict[str, float]], Place] | None = None,
             strength: str = "", **params: Param) -> Callable[[Apply], Apply]:
    """Register the decorated function as held-out implementation `family/form`."""
    return _register(IMPLEMENTATIONS, family, form, place, strength, params)


def tuning_form(family: str, form: str, place: Callable[[SonarImage, dict[str, float]], Place] | None = None,
                strength: str = "", **params: Param) -> Callable[[Apply], Apply]:
    """Register the decorated function as tuning implementation `family/form` (not held out)."""
    return _register(TUNING, family, form, place, strength, params)


def blind_form(family: str, form: str, place: Callable[[SonarImage, dict[str, float]], Place] | None = None,
               strength: str = "", **params: Param) -> Callable[[Apply], Apply]:
    """Register the decorated function as blind implementation `family/form` (the third set)."""
    return _register(BLIND, family, form, place, strength, params)


def second_blind_form(family: str, form: str, place: Callable[[SonarImage, dict[str, float]], Place] | None = None,
                      strength: str = "", **params: Param) -> Callable[[Apply], Apply]:
    """Register the decorated function as second blind implementation `family/form` (the fourth set)."""
    return _register(SECOND_BLIND, family, form, place, strength, params)


def _register(registry: dict[str, Implementation], family: str, form: str,
              place: Callable[[SonarImage, dict[str, float]], Place] | None, strength: str,
              params: dict[str, Param]) -> Callable[[Apply], Apply]:
    def register(function: Apply) -> Apply:
        entry = Implementation(family, form, (function.__doc__ or "").strip().split("\n\n")[0], function, params,
                               place, strength)
        if any(entry.name in known for known in REGISTRIES):
            raise ConfigError(f"validation implementation {entry.name} registered twice")
        if family != UNCATALOGUED and family not in EFFECTS:
            raise ConfigError(f"held-out {entry.name}: {family!r} is not a catalogue effect")
        if (family == UNCATALOGUED) != (place is not None):
            raise ConfigError(f"held-out {entry.name}: un-catalogued effects (and only they) need a place")
        registry[entry.name] = entry
        return function
    return register


def find_implementation(name: str) -> Implementation:
    """Validation implementation `name` of any set (ConfigError if none, naming the tuning forms only: the held-out
    and blind sets' names would tell whoever reads the message what the held-out half holds)."""
    entry = next((known[name] for known in REGISTRIES if name in known), None)
    if entry is None:
        unseen = sum(len(known) for known in REGISTRIES if known is not TUNING)
        raise ConfigError(f"no validation implementation {name!r}; tuning forms (registered when "
                          f"sonar_realism.diagnose.tuning_forms is imported): {sorted(TUNING)}; {unseen} more in "
                          f"the held-out and blind sets, not listed")
    return entry


def apply_held_out(frames: list[SonarImage], name: str, params: dict[str, float], seed: int) -> list[SonarImage]:
    """The "real" frames: `frames` with validation implementation `name` (of any set) applied
    (per-frame draws from `seed`)."""
    entry = find_implementation(name)
    out = []
    for index, frame in enumerate(frames):
        ping = np.random.default_rng([seed, index])
        x = frame.normalized().astype(np.float32)
        y = entry.apply(x, frame, params, ping, np.random.default_rng([seed, 7919]))
        meta = {**frame.meta, "source": "held-out", "held_out": name}
        if y.dtype == np.uint8:
            out.append(frame.replace(intensity=y, intensity_scale=255.0, meta=meta))
        else:
            clean = np.nan_to_num(np.maximum(y, 0.0), nan=0.0, posinf=0.0).astype(np.float32)
            out.append(frame.replace(intensity=clean, intensity_scale=1.0, meta=meta))
    return out


# --- small geometry helpers every family may use -------------------------------------------------------------------

def bin_m(frame: SonarImage) -> float:
    r = frame.ranges_m
    return float(r[-1] - r[0]) / max(r.size - 1, 1)


def sin_step(frame: SonarImage) -> float:
    """Beam spacing in sin(bearing) (equal for sine-spaced beams; the mean otherwise)."""
    s = np.sin(frame.azimuths_rad)
    return float(s[-1] - s[0]) / max(s.size - 1, 1)


def fft_convolve(values: np.ndarray, kernel: np.ndarray, axis: int, origin: int) -> np.ndarray:
    """`values` convolved along `axis` with `kernel`, whose tap `origin` is the zero offset (zero padded, no wrap)."""
    n = values.shape[axis]
    size = n + kernel.size
    spectrum = np.fft.rfft(values, size, axis=axis)
    shape = [1] * values.ndim
    shape[axis] = -1
    spectrum = spectrum * np.fft.rfft(kernel, size).reshape(shape)
    full = np.fft.irfft(spectrum, size, axis=axis)
    return np.take(full, np.arange(origin, origin + n), axis=axis)


def ar1(noise: np.ndarray, coefficient: float, axis: int) -> np.ndarray:
    """Unit-variance white `noise` turned into a stationary AR(1) process of lag-1 correlation `coefficient`."""
    if coefficient <= 0.0:
        return noise
    moved = np.moveaxis(noise, axis, 0).copy()
    scale = math.sqrt(1.0 - coefficient * coefficient)
    for i in range(1, moved.shape[0]):
        moved[i] = coefficient * moved[i - 1] + scale * moved[i]
    return np.moveaxis(moved, 0, axis)
