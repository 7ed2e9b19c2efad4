"""Classifier two-sample test (Lopez-Paz & Oquab 2017): can a fresh classifier tell generated from real?

A new RealismCNN is trained on part of each set and tested on the rest (contiguous folds, because
consecutive sonar frames are near duplicates and an interleaved split would test on the training set's
neighbours). Held-out balanced accuracy and ROC AUC near 0.5 mean the sets are indistinguishable; near 1
they are trivially separable. Unlike the paper's fixed real-vs-raw-sim CNN, this classifier is trained on the
very generator it judges, so it cannot be fooled by moving away from the cues raw simulation shows.

Both are scored within each fold and then pooled. The held-out half of a recording is not the half the
classifier saw, so its scores come out shifted as a whole: a fixed 0.5 threshold then calls every frame of a
fold one class (accuracy exactly 0.5 on well-separated scores), and pooling raw scores across folds mixes two
calibrations. So each fold is thresholded at its own known class proportion (the top n_real scores are called
real: label-free, chance stays 0.5), and the AUC counts only pairs within a fold.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from sonar_realism.errors import ConfigError
from sonar_realism.models.device import one_thread
from sonar_realism.models.realism_cnn import RealismCNNConfig, realism_scores, train_classifier

# A narrower net than the paper's: it is retrained per fold and per method, on tens of images.
C2ST_CLASSIFIER = RealismCNNConfig(width=8, epochs=15, dropout=0.5)


@dataclass(frozen=True)
class TwoSampleResult:
    accuracy: float  # balanced accuracy on held-out folds (0.5 = chance)
    auc: float  # ROC AUC of the held-out "real" scores (0.5 = chance)
    n_real: int
    n_generated: int


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Probability that a random positive scores above a random negative (ties count half)."""
    scores = np.asarray(scores, np.float64)
    labels = np.asarray(labels, bool)
    pos, neg = scores[labels], scores[~labels]
    if pos.size == 0 or neg.size == 0:
        raise ConfigError("roc_auc: needs both classes")
    greater = (pos[:, None] > neg[None, :]).sum()
    ties = (pos[:, None] == neg[None, :]).sum()
    return float((greater + 0.5 * ties) / (pos.size * neg.size))


@dataclass(frozen=True)
class _FoldScores:
    real: np.ndarray  # held-out "real" probabilities of the fold's real frames
    generated: np.ndarray  # and of its generated frames


def _held_out_result(folds: list[_FoldScores]) -> TwoSampleResult:
    """Balanced accuracy at each fold's class-proportion threshold and within-fold AUC, pooled over frames."""
    hits_real = hits_generated = 0
    ordered_pairs, pairs = 0.0, 0
    for fold in folds:
        scores = np.concatenate([fold.real, fold.generated])
        called_real = np.zeros(scores.size, bool)
        called_real[np.argsort(-scores, kind="stable")[:fold.real.size]] = True
        hits_real += int(called_real[:fold.real.size].sum())
        hits_generated += int((~called_real[fold.real.size:]).sum())
        labels = np.arange(scores.size) < fold.real.size
        fold_pairs = fold.real.size * fold.generated.size
        ordered_pairs += roc_auc(scores, labels) * fold_pairs
        pairs += fold_pairs
    n_real = sum(fold.real.size for fold in folds)
    n_generated = sum(fold.generated.size for fold in folds)
    balanced = 0.5 * (hits_real / n_real + hits_generated / n_generated)
    return TwoSampleResult(accuracy=float(balanced), auc=ordered_pairs / pairs, n_real=n_real,
                           n_generated=n_generated)


def _folds(n: int, k: int) -> list[np.ndarray]:
    return [chunk for chunk in np.array_split(np.arange(n), k) if chunk.size]


def classifier_two_sample_test(real: np.ndarray, generated: np.ndarray, folds: int = 2,
                               config: RealismCNNConfig = C2ST_CLASSIFIER, seed: int = 0) -> TwoSampleResult:
    """C2ST of two image sets [N, rows, cols] on the model grid, cross-validated over `folds` folds."""
    if folds < 2:
        raise ConfigError(f"folds: need >= 2, got {folds}")
    if len(real) < folds or len(generated) < folds:
        raise ConfigError(f"two-sample test: need >= {folds} images per set, got {len(real)} and {len(generated)}")
    config = replace(config, grid=tuple(real.shape[1:]), seed=seed)
    scored = []
    with one_thread():
        for real_test, gen_test in zip(_folds(len(real), folds), _folds(len(generated), folds), strict=True):
            real_train = np.delete(real, real_test, axis=0)
            gen_train = np.delete(generated, gen_test, axis=0)
            model = train_classifier(real_train, gen_train, config)
            scored.append(_FoldScores(realism_scores(model, real[real_test]),
                                      realism_scores(model, generated[gen_test])))
    return _held_out_result(scored)


@dataclass(frozen=True)
class TextureTestConfig:
    """Patch two-sample test: can a small CNN tell generated texture from real, with each patch's mean removed?

    Patches are cut from frames at their own (native) resolution, because speckle grain lives at the sensor's
    bin spacing and a model grid would resample it away. Each frame is first scaled by its maximum (the rule
    the real Oculus export follows), so contrast is comparable; removing each patch's mean leaves texture only.
    """

    patch: int = 32
    patches_per_frame: int = 24
    folds: int = 2
    epochs: int = 8
    width: int = 16
    batch_size: int = 64
    lr: float = 2e-3
    seed: int = 0

    def __post_init__(self) -> None:
        if self.patch < 8 or self.patches_per_frame < 1 or self.folds < 2 or self.epochs < 1 or self.width < 1:
            raise ConfigError(f"texture test: patch >= 8, patches_per_frame >= 1, folds >= 2, epochs >= 1 and "
                              f"width >= 1 are needed, got {self}")


def texture_patches(frames: list[np.ndarray], config: TextureTestConfig, seed: int) -> np.ndarray:
    """[len(frames), patches_per_frame, patch, patch] float32: random patches, frame-max scaled, mean removed."""
    rng = np.random.default_rng(seed)
    size = config.patch
    out = np.empty((len(frames), config.patches_per_frame, size, size), np.float32)
    for index, frame in enumerate(frames):
        image = np.asarray(frame, np.float32)
        if image.ndim != 2 or min(image.shape) < size:
            raise ConfigError(f"texture test: frame {index} has shape {image.shape}; need 2-D, sides >= {size}")
        image = image / max(float(image.max()), 1e-12)
        rows = rng.integers(0, image.shape[0] - size + 1, config.patches_per_frame)
        cols = rng.integers(0, image.shape[1] - size + 1, config.patches_per_frame)
        for k, (r, c) in enumerate(zip(rows, cols, strict=True)):
            patch = image[r:r + size, c:c + size]
            out[index, k] = patch - patch.mean()
    return out


def patch_classifier(width: int) -> torch.nn.Module:
    layers: list[torch.nn.Module] = []
    channels = 1
    for out_channels in (width, 2 * width, 2 * width):
        layers += [torch.nn.Conv2d(channels, out_channels, 3, padding=1), torch.nn.BatchNorm2d(out_channels),
                   torch.nn.LeakyReLU(0.2), torch.nn.MaxPool2d(2)]
        channels = out_channels
    layers += [torch.nn.AdaptiveAvgPool2d(1), torch.nn.Flatten(), torch.nn.Linear(channels, 1)]
    return torch.nn.Sequential(*layers)


def _train_patch_classifier(real: np.ndarray, generated: np.ndarray, config: TextureTestConfig) -> torch.nn.Module:
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    x = torch.from_numpy(np.concatenate([real, generated])).unsqueeze(1)
    y = torch.cat([torch.ones(len(real)), torch.zeros(len(generated))])
    # Inverse-frequency weights so unequal set sizes do not teach a constant answer.
    weight = torch.where(y > 0, len(y) / (2.0 * len(real)), len(y) / (2.0 * len(generated)))
    model = patch_classifier(config.width)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    for _ in range(config.epochs):
        model.train()
        for batch in torch.split(torch.from_numpy(rng.permutation(len(y))), config.batch_size):
            inputs = x[batch]
            flip = torch.from_numpy(rng.random(len(batch)) < 0.5)
            inputs = torch.where(flip[:, None, None, None], inputs.flip(-1), inputs)
            logits = model(inputs).squeeze(1)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, y[batch], weight=weight[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    model.eval()
    return model


@torch.no_grad()
def _frame_scores(model: torch.nn.Module, patches: np.ndarray) -> np.ndarray:
    """Mean "real" probability of each frame's patches, float64 [n_frames]."""
    flat = torch.from_numpy(patches.reshape(-1, 1, *patches.shape[2:]))
    probs = torch.cat([torch.sigmoid(model(batch)) for batch in torch.split(flat, 512)]).double().numpy()
    return probs.reshape(patches.shape[0], patches.shape[1]).mean(axis=1)


def texture_two_sample_test(real: list[np.ndarray], generated: list[np.ndarray],
                            config: TextureTestConfig = TextureTestConfig()) -> TwoSampleResult:
    """Patch C2ST on native-resolution frames; accuracy is per frame (its patches' scores averaged).

    Folds are contiguous in frame order (near-duplicate neighbouring pings stay on one side).
    """
    if len(real) < config.folds or len(generated) < config.folds:
        raise ConfigError(f"texture test: need >= {config.folds} frames per set, got {len(real)} and "
                          f"{len(generated)}")
    real_patches = texture_patches(real, config, config.seed)
    generated_patches = texture_patches(generated, config, config.seed + 1)
    scored = []
    flat = (-1, config.patch, config.patch)
    with one_thread():
        for real_test, gen_test in zip(_folds(len(real), config.folds), _folds(len(generated), config.folds),
                                       strict=True):
            model = _train_patch_classifier(np.delete(real_patches, real_test, axis=0).reshape(flat),
                                            np.delete(generated_patches, gen_test, axis=0).reshape(flat), config)
            scored.append(_FoldScores(_frame_scores(model, real_patches[real_test]),
                                      _frame_scores(model, generated_patches[gen_test])))
    return _held_out_result(scored)
