"""How far apart two sets of frames are: per-family and headline gaps, with bootstrap confidence intervals.

The gap of a family is the mean over its features of the squared difference of the two set means, in units of a
scale fixed once per diagnosis (the spread of that feature over the raw-sim and real frames pooled), with the
sampling bias removed (each set's variance of the mean is subtracted, as KID does for MMD). So:

- it is 0 (up to noise; it may dip slightly below) when the sets agree, about 4 per feature when they are cleanly
  separated before any correction, and it keeps falling smoothly as a correction moves the sim towards the real
  frames (the scale does not change, so the number does not saturate the way a classifier's AUC does);
- families are comparable (every feature is in "pooled spreads") and the headline is their mean.

A classifier two-sample AUC over the same features is reported alongside as the familiar, saturating number.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sonar_realism.errors import ConfigError

Stats = Mapping[str, np.ndarray]  # family -> [n_frames, n_features]


@dataclass(frozen=True)
class FeatureScale:
    """Per-family feature spreads that make gaps comparable; fixed for a whole diagnosis."""

    spread: dict[str, np.ndarray]

    @classmethod
    def pooled(cls, a: Stats, b: Stats, floor: float = 0.01) -> FeatureScale:
        """Std of every feature over the union of `a` and `b`, at least `floor` (features are fractions, contrasts,
        correlations and log powers of order 0.1-1): a feature that never varies in either set (the empty water
        column's mean, say) must not turn a tiny change into a huge gap."""
        spread = {}
        for family in a:
            union = np.concatenate([a[family], b[family]])
            spread[family] = np.maximum(union.std(axis=0), floor)
        return cls(spread)

    def families(self) -> list[str]:
        return list(self.spread)


def feature_gaps(a: Stats, b: Stats, scale: FeatureScale) -> dict[str, np.ndarray]:
    """Unbiased squared standardised mean difference of every feature: {family: [n_features]}."""
    out = {}
    for family, spread in scale.spread.items():
        x, y = a[family], b[family]
        if x.shape[0] < 2 or y.shape[0] < 2:
            raise ConfigError(f"gap: need at least 2 frames per set, got {x.shape[0]} and {y.shape[0]}")
        delta = x.mean(axis=0) - y.mean(axis=0)
        bias = x.var(axis=0, ddof=1) / x.shape[0] + y.var(axis=0, ddof=1) / y.shape[0]
        out[family] = (delta * delta - bias) / (spread * spread)
    return out


def family_gaps(a: Stats, b: Stats, scale: FeatureScale) -> dict[str, float]:
    return {family: float(values.mean()) for family, values in feature_gaps(a, b, scale).items()}


def headline(gaps: Mapping[str, float]) -> float:
    """The one number: mean of the family gaps (each family counts once, however many features it has)."""
    return float(np.mean(list(gaps.values())))


def gap(a: Stats, b: Stats, scale: FeatureScale) -> float:
    return headline(family_gaps(a, b, scale))


def gap_closed(before: float, after: float) -> float:
    """The share of the gap `before` that is gone `after` (0 when there was none)."""
    return float(1.0 - after / before) if before > 0 else 0.0


def representative_subset(stats: Stats, n: int, scale: FeatureScale) -> list[int]:
    """Indices (in order of choice) of `n` of the frames in `stats` whose mean features are closest, in `scale`'s
    spreads, to the mean over all of them: greedily, one frame at a time. A few frames drawn at random from a varied
    set (views of a scene whose level the calibrated simulator keeps) can sit far off the set's mean; a fit on them
    would spend an effect's gain on that chance offset."""
    count = _count(stats)
    target = {family: values.mean(axis=0) for family, values in stats.items()}
    chosen: list[int] = []
    sums = {family: np.zeros(values.shape[1]) for family, values in stats.items()}
    for size in range(1, min(n, count) + 1):
        left = np.setdiff1d(np.arange(count), chosen)
        distance = sum(np.mean(((sums[f][None, :] + stats[f][left]) / size - target[f]) ** 2 / spread ** 2, axis=1)
                       for f, spread in scale.spread.items())
        pick = int(left[int(np.argmin(distance))])
        chosen.append(pick)
        for family in sums:
            sums[family] += stats[family][pick]
    return chosen


def bootstrap_interval(a: Stats, b: Stats, scale: FeatureScale, n_boot: int = 200, level: float = 0.95,
                       seed: int = 0) -> tuple[float, float]:
    """Interval of the headline gap from frame resamplings of both sets (percentiles, centred on the estimate)."""
    values = _resampled(lambda ia, ib: gap(_rows(a, ia), _rows(b, ib), scale), _count(a), _count(b), n_boot, seed)
    # Resampling with replacement shifts the gap (duplicated frames look like a real difference); centre the
    # bootstrap spread on the estimate so the interval describes its uncertainty, not that shift.
    centre = gap(a, b, scale)
    lo, hi = np.quantile(values, ((1 - level) / 2, 1 - (1 - level) / 2)) - np.mean(values) + centre
    return float(lo), float(hi)


def _count(stats: Stats) -> int:
    return next(iter(stats.values())).shape[0]


def _rows(stats: Stats, index: np.ndarray) -> dict[str, np.ndarray]:
    return {family: values[index] for family, values in stats.items()}


def _resampled(statistic: Callable[[np.ndarray, np.ndarray], float | list[float]], na: int, nb: int,
               n_boot: int, seed: int) -> np.ndarray:
    """`statistic(ia, ib)` (a number or a list of them) over `n_boot` draws of frame indices with replacement: ia
    for one set, ib for the other."""
    rng = np.random.default_rng(seed)
    values = []
    for _ in range(n_boot):
        ia = rng.integers(0, na, na)
        ib = rng.integers(0, nb, nb)
        values.append(statistic(ia, ib))
    return np.array(values)


def classifier_auc(a: Stats, b: Stats, folds: int = 5, l2: float = 1.0, seed: int = 0) -> tuple[float, float]:
    """Two-sample test: cross-validated AUC of a ridge-regularised logistic regression telling `a` from `b` on all
    features, and its standard error (Hanley & McNeil). 0.5 = indistinguishable, 1.0 = always told apart."""
    x = np.concatenate([np.concatenate([a[f] for f in a], axis=1), np.concatenate([b[f] for f in a], axis=1)])
    y = np.concatenate([np.zeros(len(x) - len(next(iter(b.values())))), np.ones(len(next(iter(b.values()))))])
    n_pos, n_neg = int(y.sum()), int((1 - y).sum())
    if min(n_pos, n_neg) < 2:
        raise ConfigError(f"classifier test: need at least 2 frames per set, got {n_neg} and {n_pos}")
    folds = min(folds, n_pos, n_neg)
    order = np.random.default_rng(seed).permutation(len(y))
    scores = np.empty(len(y))
    for k in range(folds):
        test = order[k::folds]
        train = np.setdiff1d(order, test)
        mu, sd = x[train].mean(axis=0), x[train].std(axis=0) + 1e-9
        w = _fit_logistic((x[train] - mu) / sd, y[train], l2)
        scores[test] = _design((x[test] - mu) / sd) @ w
    auc = _auc(scores, y)
    q1, q2 = auc / (2 - auc), 2 * auc * auc / (1 + auc)
    se = np.sqrt(max(auc * (1 - auc) + (n_pos - 1) * (q1 - auc ** 2) + (n_neg - 1) * (q2 - auc ** 2), 0.0)
                 / (n_pos * n_neg))
    return float(auc), float(se)


def _design(x: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones(len(x)), x])


def _fit_logistic(x: np.ndarray, y: np.ndarray, l2: float, iterations: int = 25) -> np.ndarray:
    """Newton iterations on the penalised log-likelihood (features are few, so the Hessian is small)."""
    design = _design(x)
    w = np.zeros(design.shape[1])
    penalty = l2 * np.eye(design.shape[1])
    penalty[0, 0] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(design @ w, -30, 30)))
        grad = design.T @ (p - y) + penalty @ w
        hess = (design * (p * (1 - p))[:, None]).T @ design + penalty
        step = np.linalg.solve(hess + 1e-9 * np.eye(len(w)), grad)
        w -= step
        if np.abs(step).max() < 1e-6:
            break
    return w


def _auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Mann-Whitney AUC with average ranks for ties."""
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(len(scores))
    sorted_scores = scores[order]
    i = 0
    while i < len(scores):
        j = i
        while j + 1 < len(scores) and sorted_scores[j + 1] == sorted_scores[i]:
            j += 1
        ranks[order[i:j + 1]] = (i + j) / 2 + 1
        i = j + 1
    n_pos = labels.sum()
    n_neg = len(labels) - n_pos
    return float((ranks[labels == 1].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def bootstrap_gain(before: Stats, after: Stats, target: Stats, scale: FeatureScale, n_boot: int = 200,
                   level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """How much `after` lowers the gap to `target` compared with `before`, and a one-sided lower bound of that
    gain at `level`. `before` and `after` are the same frames under two corrections (row i of both comes from one
    sim frame), so frames are resampled in pairs: scene variation common to both cancels, and what is left is the
    uncertainty of the gain itself.

    The bound is the larger of the headline gain's and the best single family's contribution to it (its gain over
    the number of families, bounded at `level` Bonferroni-corrected over the families). Why: an effect acts on a
    few families (a ring-down on the range profile), and the sampling noise of the families it merely touches (the
    speckle statistics of its bright rows) can swamp the headline's interval while its own family's gain stands
    far above its noise."""
    na, nb = _count(before), _count(target)
    if _count(after) != na:
        raise ConfigError("bootstrap_gain: `before` and `after` must hold the same frames")
    families = list(scale.spread)
    was, now = family_gaps(before, target, scale), family_gaps(after, target, scale)
    point = np.array([was[f] - now[f] for f in families])
    estimate = float(point.mean())
    if n_boot < 1:
        return estimate, estimate

    def gains(ia: np.ndarray, ib: np.ndarray) -> list[float]:
        resampled_target = _rows(target, ib)
        was, now = (family_gaps(_rows(stats, ia), resampled_target, scale) for stats in (before, after))
        return [was[f] - now[f] for f in families]

    values = _resampled(gains, na, nb, n_boot, seed)  # [n_boot, families]
    # centred on the estimate, as bootstrap_interval does
    total = values.mean(axis=1)
    lower = float(np.quantile(total, 1 - level) - total.mean() + estimate)
    per_family = (np.quantile(values, (1 - level) / len(families), axis=0) - values.mean(axis=0) + point)
    return estimate, max(lower, float(per_family.max()) / len(families))


def best_frequency(candidates: Sequence[Stats | None], target: Stats, scale: FeatureScale, n_boot: int,
                   seed: int = 0) -> np.ndarray:
    """How often each candidate (the same sim frames under different corrections; None = invalid frames, never
    best) has the smallest gap to `target` over `n_boot` resamples of the frames, sim rows resampled in pairs
    across candidates and real rows on their own. Sums to 1 unless every candidate is None."""
    valid = [i for i, stats in enumerate(candidates) if stats is not None]
    wins = np.zeros(len(candidates))
    if not valid:
        return wins
    na, nb = _count(candidates[valid[0]]), _count(target)
    rng = np.random.default_rng(seed)
    for _ in range(n_boot):
        ia = rng.integers(0, na, na)
        resampled_target = _rows(target, rng.integers(0, nb, nb))
        gaps = [gap(_rows(candidates[i], ia), resampled_target, scale) for i in valid]
        wins[valid[int(np.argmin(gaps))]] += 1
    return wins / n_boot
