"""Classifier two-sample test (Lopez-Paz & Oquab 2017): can a fresh classifier tell generated from real?

A new RealismCNN is trained on part of each set and tested on the rest (contiguous folds, because
consecutive sonar frames are near duplicates and an interleaved split would test on the training set's
neighbours). Held-out balanced accuracy and ROC AUC near 0.5 mean the sets are indistinguishable; near 1
they are trivially separable. Unlike the paper's fixed real-vs-raw-sim CNN, this classifier is trained on
the very generator it judges, so it cannot be fooled by moving away from the cues raw simulation shows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sonar_realism.errors import ConfigError
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
    held_scores, held_labels = [], []
    for real_test, gen_test in zip(_folds(len(real), folds), _folds(len(generated), folds), strict=True):
        real_train = np.delete(real, real_test, axis=0)
        gen_train = np.delete(generated, gen_test, axis=0)
        model = train_classifier(real_train, gen_train, config)
        held_scores += [realism_scores(model, real[real_test]), realism_scores(model, generated[gen_test])]
        held_labels += [np.ones(len(real_test), bool), np.zeros(len(gen_test), bool)]
    scores, labels = np.concatenate(held_scores), np.concatenate(held_labels)
    predicted_real = scores > 0.5
    balanced = 0.5 * (predicted_real[labels].mean() + (~predicted_real[~labels]).mean())
    return TwoSampleResult(accuracy=float(balanced), auc=roc_auc(scores, labels), n_real=len(real),
                           n_generated=len(generated))
