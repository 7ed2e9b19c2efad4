"""The whole evaluation: Table I (the paper's realism CNN) and the metrics past the paper's.

Data discipline:
* Real frames are split in two contiguous halves (in recording order, so near-duplicate neighbouring
  pings stay on one side): the first trains the realism CNN, the second is the held-out real reference
  every metric compares against. Pass real frames no translator was trained on (e.g. the val split).
* Simulated inputs are split the same way within each category: the first half trains the realism CNN
  (against real), the second half is translated and scored. So the CNN never sees a scored image.
* Every image is compared on the model grid with the per-frame max rescale (`datasets.to_model_grid`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from sonar_realism.config import to_dict
from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.diversity import sample_diversity
from sonar_realism.evaluate.kid import kernel_inception_distance
from sonar_realism.evaluate.realism import PAPER_TABLE_I, summarize_scores
from sonar_realism.evaluate.statistics import StatisticsConfig, frame_statistics
from sonar_realism.evaluate.structure import edge_ssim, mask_iou, mask_to_grid
from sonar_realism.evaluate.texture import (
    checkerboard_score,
    histogram_distance,
    intensity_histogram,
    power_spectra,
    speckle_distance,
    speckle_statistics,
    spectral_distance,
)
from sonar_realism.evaluate.two_sample import TextureTestConfig, classifier_two_sample_test, texture_two_sample_test
from sonar_realism.frames import SonarImage
from sonar_realism.models.datasets import frames_on_grid, normalise, to_model_grid
from sonar_realism.models.realism_cnn import RealismCNNConfig, embeddings, realism_scores, train_classifier

RAW_SIM = "raw sim"
REAL_HELD_OUT = "real (held out)"
REAL_OTHER = "real (other recording)"


class Translator(Protocol):
    def translate(self, frames: Sequence[SonarImage], n: int, temperature: float = 1.0,
                  seed: int | None = None) -> list[SonarImage]: ...


@dataclass(frozen=True)
class SimInput:
    """One simulated frame, its scene category ("organic", "constructed", ...) and object mask if known."""

    frame: SonarImage
    category: str
    mask: np.ndarray | None = None


@dataclass(frozen=True)
class SuiteConfig:
    grid: tuple[int, int] = (128, 128)
    n_samples: int = 4  # samples per input from each translator (diversity needs >= 2)
    seed: int = 0
    cnn: RealismCNNConfig = field(default_factory=RealismCNNConfig)
    c2st_folds: int = 2
    kid_subsets: int = 100
    translate_batch: int = 8

    def validate(self) -> None:
        least = {"n_samples": (self.n_samples, 1), "c2st_folds": (self.c2st_folds, 2),
                 "kid_subsets": (self.kid_subsets, 1), "translate_batch": (self.translate_batch, 1)}
        for name, (value, low) in least.items():
            if value < low:
                raise ConfigError(f"evaluate: {name} must be {low} or more, got {value}")
        self.cnn.validate()


@dataclass
class SuiteResult:
    summary: dict[str, Any]  # JSON-able: the table, the metrics, the data sizes
    artifacts: dict[str, Any]  # arrays for the figures


def _halves(n: int) -> tuple[np.ndarray, np.ndarray]:
    first = np.arange(n // 2)
    return first, np.arange(n // 2, n)


def _translate(translator: Translator, frames: list[SonarImage], config: SuiteConfig, name: str
               ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Outputs of one translator on the model grid, [n_inputs, n_samples, rows, cols], and each input's first
    sample at its own resolution (frame-max scaled), for the texture test."""
    out, native = [], []
    batches = [frames[i:i + config.translate_batch] for i in range(0, len(frames), config.translate_batch)]
    for index, batch in enumerate(tqdm(batches, desc=f"translate ({name})", unit="batch")):
        results = translator.translate(batch, n=config.n_samples, seed=config.seed + index)
        for result in results:
            out.append(to_model_grid(result, config.grid, "frame_max").reshape(-1, *config.grid))
            native.append(normalise(result.sample(0), "frame_max"))
    return np.stack(out), native


def _epoch_bar(label: str) -> Callable[[int, int, float], None]:
    """A `progress(epoch, epochs, loss)` callback drawing a tqdm bar over the epochs."""
    bar: tqdm | None = None

    def callback(epoch: int, epochs: int, loss: float) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=epochs, desc=label, unit="epoch")
        bar.update(epoch - bar.n)
        bar.set_postfix(loss=f"{loss:.4f}")
        if epoch == epochs:
            bar.close()

    return callback


def family_gaps(images: np.ndarray, reference: np.ndarray) -> dict[str, float] | None:
    """Per statistics family (diagnose's `frame_statistics`): mean over features of |Δ mean| / std of real.

    None when the grid is smaller than the statistics are defined on.
    """
    if any(side < need for side, need in zip(images.shape[1:], StatisticsConfig().min_shape(), strict=True)):
        return None
    ours, real = frame_statistics(images), frame_statistics(reference)
    return {family: float(np.mean(np.abs(ours[family].mean(axis=0) - real[family].mean(axis=0))
                                  / (real[family].std(axis=0) + 1e-3))) for family in real}


def _method_metrics(outputs: np.ndarray, native: list[np.ndarray], inputs: np.ndarray,
                    masks: list[np.ndarray | None], reference: np.ndarray, reference_native: list[np.ndarray],
                    reference_features: np.ndarray, cnn: Any, config: SuiteConfig, name: str) -> dict[str, Any]:
    first = outputs[:, 0]
    c2st = classifier_two_sample_test(reference, first, folds=config.c2st_folds, seed=config.seed)
    texture_c2st = texture_two_sample_test(reference_native, native, TextureTestConfig(seed=config.seed))
    kid = kernel_inception_distance(reference_features, embeddings(cnn, first), n_subsets=config.kid_subsets,
                                    seed=config.seed)
    spectra, real_spectra = power_spectra(first), power_spectra(reference)
    ious = [mask_iou(mask, out, source) for mask, out, source in zip(masks, first, inputs, strict=True)
            if mask is not None and mask.any()]
    metrics: dict[str, Any] = {
        "c2st": dataclasses.asdict(c2st),
        "texture_c2st": dataclasses.asdict(texture_c2st),
        "kid": dataclasses.asdict(kid),
        "spectral_distance": spectral_distance(spectra, real_spectra),
        "checkerboard": checkerboard_score(spectra),
        "speckle_distance": speckle_distance(speckle_statistics(first), speckle_statistics(reference)),
        "histogram_distance": histogram_distance(first, reference),
        "edge_ssim": float(np.mean([edge_ssim(a, b) for a, b in zip(inputs, first, strict=True)])),
        "mask_iou": float(np.mean(ious)) if ious else None,
        "family_gaps": family_gaps(first, reference),
        "diversity": None,
    }
    if name != RAW_SIM and outputs.shape[1] >= 2 and len(outputs) >= 2:
        metrics["diversity"] = dataclasses.asdict(sample_diversity(outputs))
    return metrics


def run_suite(real_frames: Sequence[SonarImage], sim_inputs: Sequence[SimInput], translators: dict[str, Translator],
              config: SuiteConfig | None = None, log: Callable[[str], None] = lambda _: None,
              other_real: Sequence[SonarImage] = ()) -> SuiteResult:
    """Train the realism CNN, translate the scored sim inputs, and compute every metric per method.

    `other_real`: real frames of another recording of the sensor (e.g. the translators' training recording),
    scored by the realism CNN as a yardstick in Table I: what the CNN, trained on one recording against the
    simulator, makes of real frames from outside that recording (on the Oculus set it calls the other recording
    simulated, docs/RESULTS.md)."""
    config = config or SuiteConfig()
    config.validate()
    reserved = (RAW_SIM, REAL_HELD_OUT, REAL_OTHER)
    if any(name in translators for name in reserved):
        raise ConfigError(f"translator names {', '.join(map(repr, reserved))} are reserved")
    real = frames_on_grid(real_frames, config.grid)
    other = frames_on_grid(other_real, config.grid) if other_real else None
    if len(real) < 2 * config.c2st_folds:
        raise ConfigError(f"need at least {2 * config.c2st_folds} real frames, got {len(real)}")
    real_cnn_idx, real_ref_idx = _halves(len(real))
    reference = real[real_ref_idx]
    single_real = [frame.sample(0) if frame.intensity.ndim == 3 else frame for frame in real_frames]
    reference_native = [normalise(single_real[i], "frame_max") for i in real_ref_idx[real_ref_idx < len(single_real)]]

    categories = sorted({item.category for item in sim_inputs})
    train_sim, scored = [], []
    for category in categories:
        items = [item for item in sim_inputs if item.category == category]
        if len(items) < 2:
            raise ConfigError(f"category {category!r}: need at least 2 simulated frames, got {len(items)}")
        first, second = _halves(len(items))
        train_sim += [items[i] for i in first]
        scored += [items[i] for i in second]
    if len(scored) < config.c2st_folds:
        raise ConfigError(f"need at least {2 * config.c2st_folds} simulated frames, got {len(sim_inputs)}")

    def sim_grid(item: SimInput) -> np.ndarray:
        frame = item.frame.sample(0) if item.frame.intensity.ndim == 3 else item.frame
        return to_model_grid(frame, config.grid, "frame_max")

    log(f"realism CNN: {len(real_cnn_idx)} real vs {len(train_sim)} simulated frames")
    cnn = train_classifier(real[real_cnn_idx], np.stack([sim_grid(i) for i in train_sim]),
                           dataclasses.replace(config.cnn, grid=config.grid, seed=config.seed),
                           progress=_epoch_bar("realism CNN"))
    inputs = np.stack([sim_grid(item) for item in scored])
    masks = [mask_to_grid(item.mask, item.frame, config.grid) if item.mask is not None else None for item in scored]
    outputs = {RAW_SIM: inputs[:, None]}
    frames = [item.frame.sample(0) if item.frame.intensity.ndim == 3 else item.frame for item in scored]
    natives = {RAW_SIM: [normalise(frame, "frame_max") for frame in frames]}
    for name, translator in translators.items():
        outputs[name], natives[name] = _translate(translator, frames, config, name)

    labels = np.array([item.category for item in scored])
    table: dict[str, dict[str, Any]] = {category: {} for category in [*categories, "all"]}
    for name, out in outputs.items():
        per_input = realism_scores(cnn, out.reshape(-1, *config.grid)).reshape(len(out), -1).mean(axis=1)
        for category in table:
            chosen = per_input if category == "all" else per_input[labels == category]
            table[category][name] = dataclasses.asdict(summarize_scores(chosen, seed=config.seed))
    table["all"][REAL_HELD_OUT] = dataclasses.asdict(summarize_scores(realism_scores(cnn, reference), config.seed))
    if other is not None:
        table["all"][REAL_OTHER] = dataclasses.asdict(summarize_scores(realism_scores(cnn, other), config.seed))

    reference_features = embeddings(cnn, reference)
    methods = {}
    for name in tqdm(list(outputs), desc="metrics", unit="method"):
        methods[name] = _method_metrics(outputs[name], natives[name], inputs, masks, reference, reference_native,
                                        reference_features, cnn, config, name)

    spectra = {name: power_spectra(out[:, 0]) for name, out in outputs.items()}
    spectra["real"] = power_spectra(reference)
    summary = {
        "config": to_dict(config),
        "data": {"n_real": len(real), "n_real_cnn": len(real_cnn_idx), "n_real_reference": len(reference),
                 "n_real_other": 0 if other is None else len(other),
                 "n_sim_cnn": len(train_sim), "n_sim_scored": len(scored),
                 "sim_scored_per_category": {c: int((labels == c).sum()) for c in categories}},
        "table": table,
        "methods": methods,
        "real_reference": {"checkerboard": checkerboard_score(spectra["real"]),
                           "speckle": [dataclasses.asdict(b) for b in speckle_statistics(reference)]},
        "speckle": {name: [dataclasses.asdict(b) for b in speckle_statistics(out[:, 0])]
                    for name, out in outputs.items()},
        "paper_table_i": PAPER_TABLE_I,
    }
    first = frames[0]
    artifacts = {"outputs": outputs, "inputs": inputs, "labels": labels, "reference": reference, "spectra": spectra,
                 "fan_extent": (float(first.ranges_m[0]), float(first.ranges_m[-1]), float(first.azimuths_rad[0]),
                                float(first.azimuths_rad[-1])),
                 "histograms": {**{n: intensity_histogram(o[:, 0]) for n, o in outputs.items()},
                                "real": intensity_histogram(reference)}}
    return SuiteResult(summary=summary, artifacts=artifacts)
