"""Fit the full-effect simulator's default parameters to real Oculus frames, and show the match before and after.

    python -m sonar_realism.sim.calibrate --real "$SONAR_REALISM_DATA"/real/oculus_polar_seabed/dataset --out docs/img

The real frames are 8-bit polar images rescaled per frame so that the maximum is 255; simulated frames go through
the same rescale before they are compared. Four targets, each one number or a short vector:

- intensity histogram (Wasserstein-1 distance between the grey-level distributions);
- speckle grain: autocorrelation of the detrended image at lags 1-3 across beams and along range;
- range profile: row mean against normalised range (TVG, seabed band) and the row 10th percentile (noise floor);
- near-field band: mean of the first 2 % of rows (ring-down) and of the next 2-8 % (the dark zone behind it).

The fit is a pattern search over the effects' PARAM_BOUNDS with common random numbers (fixed frames, fixed seeds),
so the loss is a deterministic function of the parameters.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sonar_realism import plots
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.sim.effects import (
    EFFECTS,
    PIPELINE_ORDER,
    Effect,
    apply_effects,
    calibrated_parameters,
    make_effect,
)
from sonar_realism.sim.simulate import simulate

PROFILE_BINS = 48
HIST_BINS = 64
MAX_LAG = 3
DETREND_BOX = 9

# (effect, parameter, log-scale search) fitted by the calibration (declared by each effect class).
FITTED: tuple[tuple[str, str, bool], ...] = calibrated_parameters()


@dataclass(frozen=True)
class Fingerprint:
    """The calibration targets of a set of frames (all in 8-bit units / 255)."""

    histogram: np.ndarray  # [HIST_BINS] density over [0, 1]
    acf_beams: np.ndarray  # [MAX_LAG]
    acf_ranges: np.ndarray  # [MAX_LAG]
    row_mean: np.ndarray  # [PROFILE_BINS]
    row_floor: np.ndarray  # [PROFILE_BINS]
    near_band: float
    dark_zone: float

    def as_dict(self) -> dict[str, Any]:
        return {k: (v.round(4).tolist() if isinstance(v, np.ndarray) else round(v, 4))
                for k, v in dataclasses.asdict(self).items()}


def per_frame_rescaled(image: np.ndarray) -> np.ndarray:
    """What the real set's export did: raw * 255 / raw.max(), as float in [0, 1]."""
    image = image.astype(np.float32)
    peak = float(image.max())
    return image / peak if peak > 0 else image


def _resample(profile: np.ndarray, bins: int) -> np.ndarray:
    x = (np.arange(profile.size) + 0.5) / profile.size
    return np.interp((np.arange(bins) + 0.5) / bins, x, profile)


def _acf(detrended: np.ndarray, weight: np.ndarray, axis: int) -> np.ndarray:
    out = np.empty(MAX_LAG)
    var = float((detrended * detrended * weight).sum()) + 1e-12
    n = detrended.shape[axis]
    for lag in range(1, MAX_LAG + 1):
        a = detrended.take(np.arange(n - lag), axis=axis)
        b = detrended.take(np.arange(lag, n), axis=axis)
        w = weight.take(np.arange(n - lag), axis=axis) * weight.take(np.arange(lag, n), axis=axis)
        out[lag - 1] = float((a * b * w).sum()) / var
    return out


def fingerprint(images: Sequence[np.ndarray]) -> Fingerprint:
    """Targets of images already rescaled to [0, 1] (each [n_ranges, n_beams], any n_ranges)."""
    if not images:
        raise ConfigError("calibrate: no frames to measure")
    hist = np.zeros(HIST_BINS)
    acf_b, acf_r = np.zeros(MAX_LAG), np.zeros(MAX_LAG)
    means, floors, near, dark = [], [], [], []
    for image in images:
        hist += np.histogram(image, bins=HIST_BINS, range=(0.0, 1.0))[0]
        local = cv2.blur(image, (DETREND_BOX, DETREND_BOX), borderType=cv2.BORDER_REFLECT_101)
        detrended = image - local
        # grain is measured where there is signal (seabed, targets): local mean above the frame median
        weight = (local > np.median(local)).astype(np.float32)
        acf_b += _acf(detrended, weight, axis=1)
        acf_r += _acf(detrended, weight, axis=0)
        means.append(_resample(image.mean(axis=1), PROFILE_BINS))
        floors.append(_resample(np.percentile(image, 10, axis=1), PROFILE_BINS))
        rows = image.shape[0]
        near.append(float(image[: max(1, rows // 50)].mean()))
        dark.append(float(image[max(1, rows // 50): max(2, rows * 8 // 100)].mean()))
    n = len(images)
    return Fingerprint(hist / hist.sum() * HIST_BINS, acf_b / n, acf_r / n, np.mean(means, axis=0),
                       np.mean(floors, axis=0), float(np.mean(near)), float(np.mean(dark)))


def distance(sim: Fingerprint, real: Fingerprint) -> dict[str, float]:
    """Per-target mismatch (all O(0.01-0.1) when close) and their sum `total`."""
    cdf_sim = np.cumsum(sim.histogram) / HIST_BINS
    cdf_real = np.cumsum(real.histogram) / HIST_BINS
    parts = {
        "histogram_w1": float(np.abs(cdf_sim - cdf_real).mean()),
        "grain_beams": float(np.abs(sim.acf_beams - real.acf_beams).mean()),
        "grain_ranges": float(np.abs(sim.acf_ranges - real.acf_ranges).mean()),
        "range_profile": float(np.abs(sim.row_mean - real.row_mean).mean()),
        "noise_floor": float(np.abs(sim.row_floor - real.row_floor).mean()),
        "near_band": abs(sim.near_band - real.near_band) + abs(sim.dark_zone - real.dark_zone),
    }
    parts["total"] = float(sum(parts.values()))
    return parts


def load_real(root: Path, limit: int | None = None) -> list[np.ndarray]:
    """Real 8-bit polar PNGs under `root` (any depth), as float [0, 1] rescaled per frame like the export."""
    paths = sorted(p for p in root.rglob("*.png") if p.is_file())
    if limit:
        paths = paths[:: max(1, len(paths) // limit)][:limit]
    images = []
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ConfigError(f"{path}: not a readable PNG")
        images.append(per_frame_rescaled(image))
    if not images:
        raise ConfigError(f"{root}: no PNG frames found")
    return images


def render_clean(n_frames: int, seed: int, scene: str = "default") -> list[SonarImage]:
    return [frame for frame, _ in simulate(scene, "none", n_frames, seed)]


def with_effects(clean: Sequence[SonarImage], effects: Sequence[Effect], seed: int) -> list[np.ndarray]:
    """The clean frames through `effects`, rescaled per frame like the real export (same seeds every call)."""
    out = []
    for i, frame in enumerate(clean):
        result = apply_effects(frame, effects, np.random.default_rng([seed, i]))
        out.append(per_frame_rescaled(result.intensity))
    return out


def effects_from(values: dict[tuple[str, str], float], base: dict[str, Effect] | None = None) -> list[Effect]:
    """The full effect chain with `values` overriding the defaults (or `base`)."""
    chain = dict(base or {name: EFFECTS[name]() for name in PIPELINE_ORDER})
    for (name, param), value in values.items():
        chain[name] = dataclasses.replace(chain[name], **{param: value})
    return [chain[name] for name in PIPELINE_ORDER]


def fit(clean: Sequence[SonarImage], target: Fingerprint, seed: int, rounds: int = 6,
        log: Any = None) -> tuple[list[Effect], float]:
    """Pattern search over FITTED in normalised coordinates; returns the best chain and its loss."""
    bounds = {(e, p): EFFECTS[e].PARAM_BOUNDS[p] for e, p, _ in FITTED}
    is_log = {(e, p): use_log for e, p, use_log in FITTED}

    def to_unit(key: tuple[str, str], value: float) -> float:
        lo, hi = bounds[key]
        if is_log[key]:
            return (math.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo))
        return (value - lo) / (hi - lo)

    def from_unit(key: tuple[str, str], u: float) -> float:
        lo, hi = bounds[key]
        u = min(max(u, 0.0), 1.0)
        return math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if is_log[key] else lo + u * (hi - lo)

    defaults = {name: EFFECTS[name]() for name in PIPELINE_ORDER}
    point = {key: to_unit(key, min(max(getattr(defaults[key[0]], key[1]), bounds[key][0]), bounds[key][1]))
             for key in bounds}

    def loss(p: dict[tuple[str, str], float]) -> float:
        chain = effects_from({k: from_unit(k, u) for k, u in p.items()}, defaults)
        return distance(fingerprint(with_effects(clean, chain, seed)), target)["total"]

    best = loss(point)
    step = 0.25
    for round_index in range(rounds):
        for key in bounds:
            trials = []
            for direction in (+1, -1):
                trial = dict(point)
                trial[key] = min(max(point[key] + direction * step, 0.0), 1.0)
                if trial[key] != point[key]:
                    trials.append((loss(trial), trial))
            if trials:
                value, trial = min(trials, key=lambda pair: pair[0])
                if value < best:
                    best, point = value, trial
        if log:
            print(f"calibrate: round {round_index + 1}/{rounds}, step {step:.3f}, loss {best:.4f}", file=log)
        step /= 2
    fitted = {k: from_unit(k, u) for k, u in point.items()}
    return effects_from({k: _round(v) for k, v in fitted.items()}, defaults), best


def _round(value: float) -> float:
    """Three significant digits: what gets baked into the defaults."""
    if value == 0:
        return 0.0
    return float(f"{value:.3g}")


def write_plots(out: Path, real: Fingerprint, fingerprints: dict[str, Fingerprint],
                examples: dict[str, list[np.ndarray]]) -> list[Path]:
    x_hist = (np.arange(HIST_BINS) + 0.5) / HIST_BINS
    x_prof = (np.arange(PROFILE_BINS) + 0.5) / PROFILE_BINS
    lags = np.arange(1, MAX_LAG + 1, dtype=float)
    all_sets = {"real": real, **fingerprints}
    paths = [
        plots.line_plot({k: (x_hist, np.log10(f.histogram + 1e-3)) for k, f in all_sets.items()},
                        out / "sim_calibration_histogram.png", "grey-level histogram (per-frame max = 1)",
                        "grey level / 255", "log10 density"),
        plots.line_plot({k: (x_prof, f.row_mean) for k, f in all_sets.items()},
                        out / "sim_calibration_range_profile.png", "row mean against range", "range / max range",
                        "mean grey / 255"),
        plots.line_plot({k: (x_prof, f.row_floor) for k, f in all_sets.items()},
                        out / "sim_calibration_noise_floor.png", "row 10th percentile (noise floor) against range",
                        "range / max range", "grey / 255"),
        plots.line_plot({**{f"{k} beams": (lags, f.acf_beams) for k, f in all_sets.items()},
                         **{f"{k} ranges": (lags, f.acf_ranges) for k, f in all_sets.items()}},
                        out / "sim_calibration_grain.png", "speckle grain: autocorrelation of detrended image",
                        "lag (pixels)", "correlation"),
    ]
    grid, labels = [], []
    for name, images in examples.items():
        for image in images:
            grid.append(cv2.resize((image * 255).astype(np.uint8), (192, 288), interpolation=cv2.INTER_AREA))
            labels.append(name)
    paths.append(plots.image_grid(grid, out / "sim_calibration_examples.png", ncols=len(grid) // len(examples),
                                  labels=labels))
    return paths


def markdown_table(rows: dict[str, dict[str, float]]) -> str:
    keys = list(next(iter(rows.values())))
    lines = ["| set | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for name, parts in rows.items():
        lines.append(f"| {name} | " + " | ".join(f"{parts[k]:.4f}" for k in keys) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sonar_realism.sim.calibrate", description=__doc__.splitlines()[0])
    parser.add_argument("--real", required=True, help="folder of real 8-bit polar PNGs (searched recursively)")
    parser.add_argument("--out", required=True, help="folder for the plots (docs/img)")
    parser.add_argument("--frames", type=int, default=8, help="simulated frames used in the fit (default 8)")
    parser.add_argument("--rounds", type=int, default=6, help="pattern-search rounds (default 6)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="also write the result (fitted parameters, distances) to this JSON file")
    args = parser.parse_args(argv)

    real_images = load_real(Path(args.real))
    target = fingerprint(real_images)
    clean = render_clean(args.frames, args.seed)
    defaults = [make_effect(name) for name in PIPELINE_ORDER]
    raw_fp = fingerprint([per_frame_rescaled(f.intensity) for f in clean])
    before_fp = fingerprint(with_effects(clean, defaults, args.seed))
    fitted, _ = fit(clean, target, args.seed, args.rounds, log=sys.stderr)
    after_fp = fingerprint(with_effects(clean, fitted, args.seed))
    rows = {"raw sim": distance(raw_fp, target), "all effects, defaults": distance(before_fp, target),
            "all effects, fitted": distance(after_fp, target)}

    out = Path(args.out)
    # real frames are never drawn into the output: the real set may not be redistributed (see its README)
    examples = {"raw sim": [per_frame_rescaled(f.intensity) for f in clean[:3]],
                "defaults": with_effects(clean[:3], defaults, args.seed),
                "fitted": with_effects(clean[:3], fitted, args.seed)}
    written = write_plots(out, target, {"raw sim": raw_fp, "defaults": before_fp, "fitted": after_fp}, examples)

    changed = {e.name: {k: v for k, v in e.params().items() if v != EFFECTS[e.name]().params()[k]} for e in fitted}
    result = {"real_frames": len(real_images), "sim_frames": len(clean), "distances": rows,
              "fitted_params": {e.name: e.params() for e in fitted},
              "changed_from_defaults": {k: v for k, v in changed.items() if v},
              "real_fingerprint": target.as_dict(), "fitted_fingerprint": after_fp.as_dict(),
              "plots": [str(p) for p in written]}
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print(markdown_table(rows))
    print(json.dumps({"changed_from_defaults": result["changed_from_defaults"]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
