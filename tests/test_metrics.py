"""Each evaluation metric on constructed cases whose answer is known."""

import cv2
import numpy as np
import pytest

from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.diversity import sample_diversity
from sonar_realism.evaluate.kid import kernel_inception_distance
from sonar_realism.evaluate.realism import bootstrap_ci, summarize_scores
from sonar_realism.evaluate.structure import edge_ssim, mask_iou, ssim
from sonar_realism.evaluate.texture import (
    checkerboard_score,
    histogram_distance,
    power_spectra,
    range_asymmetry,
    speckle_statistics,
    spectral_distance,
)
from sonar_realism.evaluate.two_sample import classifier_two_sample_test, roc_auc

GRID = 32


def clean_scenes(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Simulator-like clean frames: a dim seabed ramp with one bright box and its shadow; and the box masks."""
    rng = np.random.default_rng(seed)
    images = np.zeros((n, GRID, GRID), np.float32)
    masks = np.zeros((n, GRID, GRID), np.uint8)
    ramp = np.linspace(0.2, 0.4, GRID, dtype=np.float32)[:, None]
    for i in range(n):
        r, c = rng.integers(6, GRID - 14), rng.integers(4, GRID - 10)
        images[i] = ramp
        images[i, r:r + 5, c:c + 6] = 1.0
        images[i, r + 5:, c:c + 6] = 0.02  # acoustic shadow behind the object
        masks[i, r:r + 5, c:c + 6] = 1
    return images, masks


def speckled(images: np.ndarray, seed: int) -> np.ndarray:
    """The 'real sensor' effect: fully developed (Rayleigh) speckle on the clean amplitude, max-rescaled."""
    rng = np.random.default_rng(seed)
    out = images * rng.rayleigh(1.0 / np.sqrt(np.pi / 2), images.shape).astype(np.float32)
    return out / out.max(axis=(1, 2), keepdims=True)


def test_kid_is_near_zero_for_one_distribution_and_large_for_a_shift():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(200, 16)), rng.normal(size=(200, 16))
    same = kernel_inception_distance(x, y, n_subsets=20, subset_size=100)
    shifted = kernel_inception_distance(x, y + 1.0, n_subsets=20, subset_size=100)
    identical = kernel_inception_distance(x, x, n_subsets=20, subset_size=100)
    assert abs(same.mean) < 0.1 and abs(identical.mean) < 0.1  # unbiased: noise around 0, may be negative
    assert shifted.mean > 1.0
    with pytest.raises(ConfigError):
        kernel_inception_distance(x, rng.normal(size=(10, 3)))


def test_a_known_blur_moves_the_spectral_distance_and_identical_sets_have_none():
    images = speckled(clean_scenes(20, 0)[0], 1)
    blurred = np.stack([cv2.GaussianBlur(im, (0, 0), s) for im, s in zip(images, [1.0] * 20, strict=True)])
    more = np.stack([cv2.GaussianBlur(im, (0, 0), 2.0) for im in images])
    reference = power_spectra(images)
    assert spectral_distance(reference, power_spectra(images.copy())) == 0.0
    light = spectral_distance(reference, power_spectra(blurred))
    heavy = spectral_distance(reference, power_spectra(more))
    assert 0.1 < light < heavy
    # Blur takes power from high frequencies: the radial spectrum's tail drops.
    assert power_spectra(blurred).radial[-3:].mean() < reference.radial[-3:].mean() - 0.5


def test_checkerboard_score_flags_a_stride_two_pattern():
    images = speckled(clean_scenes(20, 0)[0], 1)
    pattern = np.indices((GRID, GRID)).sum(axis=0) % 2 * 0.3  # period 2 along both axes
    artefact = images + pattern[None].astype(np.float32)
    assert checkerboard_score(power_spectra(images)) < 0.5
    assert checkerboard_score(power_spectra(artefact)) > 1.0


def test_speckle_statistics_recover_rayleigh_and_see_heavier_tails():
    rng = np.random.default_rng(0)
    rayleigh = rng.rayleigh(1.0, (10, 64, 64))
    bands = speckle_statistics(rayleigh)
    assert len(bands) == 4
    for band in bands:
        assert band.contrast == pytest.approx(0.5227, abs=0.03)
        assert band.weibull_k == pytest.approx(2.0, abs=0.15)
    # K-distributed amplitude: Rayleigh with a gamma-distributed (shape 1) local power -> heavier tail.
    k_amplitude = rayleigh * np.sqrt(rng.gamma(1.0, 1.0, rayleigh.shape))
    k_band = speckle_statistics(k_amplitude)[0]
    assert k_band.contrast > bands[0].contrast + 0.1
    assert k_band.k_shape < 5 and k_band.weibull_k < 1.8


def test_range_asymmetry_reads_the_direction_of_range_that_grain_and_spectrum_cannot() -> None:
    """Sparse bright scatterers each followed by a slow decay along range (a sharp rise, a slow fall) read > 0,
    the same frames read backwards < 0 by as much, and symmetric speckle of the same grain about 0."""
    rng = np.random.default_rng(0)
    rows, cols = 200, 64
    decay = 0.8 ** np.arange(12)
    frames, speckle = [], []
    for _ in range(6):
        impulses = rng.gamma(0.3, 1.0, (rows, cols)) * (rng.random((rows, cols)) < 0.15)
        tails = sum(decay[k] * np.roll(impulses, k, axis=0) for k in range(decay.size))
        frames.append((0.05 + tails).astype(np.float32))
        gaussian = cv2.GaussianBlur(rng.standard_normal((rows, cols)).astype(np.float32), (0, 0), 1.5)
        speckle.append(np.exp(gaussian).astype(np.float32))
    forward = range_asymmetry(frames)
    assert forward > 0.3
    assert range_asymmetry([f[::-1] for f in frames]) == pytest.approx(-forward, abs=0.05)
    assert abs(range_asymmetry(speckle)) < 0.1


def test_histogram_distance_zero_for_identical_and_grows_with_gain():
    images = speckled(clean_scenes(10, 0)[0], 1)
    assert histogram_distance(images, images) == 0.0
    assert histogram_distance(images, images * 0.5) > histogram_distance(images, images * 0.9) > 0


def test_diversity_is_zero_for_a_collapsed_generator_and_positive_for_sampling():
    clean = clean_scenes(6, 0)[0]
    collapsed = np.repeat(speckled(clean, 1)[:, None], 4, axis=1)
    sampled = np.stack([speckled(clean, seed) for seed in range(4)], axis=1)
    assert sample_diversity(collapsed).relative == 0.0
    assert sample_diversity(collapsed).pixel_std == 0.0
    result = sample_diversity(sampled)
    assert 0.2 < result.relative < 1.5 and result.pairwise_l1 > 0.01
    with pytest.raises(ConfigError):
        sample_diversity(collapsed[:, :1])


def test_structure_metrics_keep_the_scene_and_reject_another():
    clean, masks = clean_scenes(2, 3)
    translated = speckled(clean, 5)
    assert ssim(clean[0], clean[0]) == pytest.approx(1.0)
    assert edge_ssim(clean[0], translated[0]) > edge_ssim(clean[0], translated[1]) + 0.05
    assert mask_iou(masks[0], clean[0]) > 0.8  # the blur that suppresses speckle rounds the box corners
    assert mask_iou(masks[0], translated[0]) > mask_iou(masks[0], translated[1])
    assert np.isnan(mask_iou(np.zeros_like(masks[0]), clean[0]))


def test_mask_iou_finds_a_target_darker_than_a_bright_seabed_and_loses_it_when_the_output_does():
    """A calibrated seabed is often brighter than its targets, and a bright band elsewhere takes the frame's
    brightest cells: the object is sought as what stands out near it, in the polarity the sim input gives it."""
    rng = np.random.default_rng(4)
    seabed = np.full((64, 64), 0.5, np.float32) * rng.rayleigh(0.8, (64, 64)).astype(np.float32)
    seabed[50:56] = 1.0  # a bright band far from the target
    with_target = seabed.copy()
    with_target[20:26, 30:38] *= 0.35  # a dim target on the lit seabed
    mask = np.zeros((64, 64), np.uint8)
    mask[20:26, 30:38] = 1
    kept = with_target * rng.rayleigh(0.8, (64, 64)).astype(np.float32)  # new speckle, same scene
    inverted = seabed.copy()
    inverted[20:26, 30:38] = 1.0  # an output that made the dark target bright
    on_input = mask_iou(mask, with_target)
    assert on_input > 0.4
    assert mask_iou(mask, kept, with_target) > 0.6 * on_input
    assert mask_iou(mask, seabed, with_target) < 0.2  # the output lost the target
    assert mask_iou(mask, inverted, with_target) < 0.1  # sought as dark, as the input has it
    assert mask_iou(mask, inverted) > 0.8  # by its own polarity the bright patch is found
    with pytest.raises(ConfigError, match="reference"):
        mask_iou(mask, kept, with_target[:10])


def test_roc_auc_and_bootstrap_known_values():
    assert roc_auc(np.array([0.9, 0.8, 0.1, 0.2]), np.array([1, 1, 0, 0])) == 1.0
    assert roc_auc(np.array([0.5, 0.5]), np.array([1, 0])) == 0.5
    values = np.random.default_rng(0).normal(0.3, 0.1, 400)
    low, high = bootstrap_ci(values)
    assert low < 0.3 < high and high - low < 0.05
    summary = summarize_scores(values)
    assert summary.p10 < summary.mean < summary.p90 and summary.n == 400


def test_two_sample_test_near_chance_for_a_perfect_translator_and_high_for_raw_sim():
    clean, _ = clean_scenes(48, 0)
    real = speckled(clean[:24], seed=1)
    # A perfect translator applies the real sensor's own effect (same process, fresh noise) to new scenes.
    perfect = speckled(clean[24:], seed=2)
    raw = clean[24:] / clean[24:].max(axis=(1, 2), keepdims=True)
    indistinguishable = classifier_two_sample_test(real, perfect, folds=2, seed=0)
    separable = classifier_two_sample_test(real, raw, folds=2, seed=0)
    assert abs(indistinguishable.accuracy - 0.5) < 0.2
    assert separable.accuracy > 0.9 and separable.auc > 0.9


def test_two_sample_figures_do_not_depend_on_the_thread_count() -> None:
    """torch's CPU kernels split sums by thread: unpinned, one texture test read 0.92 on two threads and 0.99 on
    one. Both tests now train on one thread and give the caller's thread count back, even after an error."""
    import torch

    from sonar_realism.evaluate.two_sample import TextureTestConfig, texture_two_sample_test
    from sonar_realism.models.device import one_thread

    rng = np.random.default_rng(3)
    real = [rng.gamma(1.0, 1.0, (64, 64)).astype(np.float32) for _ in range(12)]
    near = [rng.gamma(1.1, 1.0, (64, 64)).astype(np.float32) for _ in range(12)]
    config = TextureTestConfig(epochs=2, patches_per_frame=8)
    before = torch.get_num_threads()
    try:
        results = []
        for threads in (2, 1):
            torch.set_num_threads(threads)
            results.append(texture_two_sample_test(real, near, config))
            assert torch.get_num_threads() == threads
        assert results[0] == results[1]
        with pytest.raises(RuntimeError), one_thread():
            assert torch.get_num_threads() == 1
            raise RuntimeError("inside")
        assert torch.get_num_threads() == 1  # the count set before it, given back
    finally:
        torch.set_num_threads(before)


def test_two_sample_scores_each_fold_on_its_own_so_a_shifted_fold_does_not_collapse_to_chance():
    from sonar_realism.evaluate.two_sample import _FoldScores, _held_out_result

    # Separated within each fold, but the second fold's scores all sit below 0.5 (a held-out half the classifier
    # was not calibrated on): a fixed 0.5 threshold would call that whole fold generated, pooled AUC would mix them.
    shifted = [_FoldScores(np.array([0.9, 0.8, 0.85]), np.array([0.6, 0.55])),
               _FoldScores(np.array([0.3, 0.35]), np.array([0.1, 0.2, 0.15]))]
    result = _held_out_result(shifted)
    assert result.accuracy == 1.0 and result.auc == 1.0 and (result.n_real, result.n_generated) == (5, 5)
    mixed = _held_out_result([_FoldScores(np.array([0.9, 0.1]), np.array([0.5, 0.6]))])
    assert mixed.accuracy == 0.5 and mixed.auc == 0.5


def test_family_gaps_from_the_shared_statistics_are_zero_for_identical_sets():
    from sonar_realism.evaluate.suite import family_gaps

    rng = np.random.default_rng(0)
    images = (rng.rayleigh(0.2, (6, 128, 128))).clip(0, 1).astype(np.float32)
    same = family_gaps(images, images)
    assert same is not None and max(same.values()) == 0.0
    blurred = np.stack([cv2.GaussianBlur(im, (0, 0), 2.0) for im in images])
    assert family_gaps(blurred, images)["grain"] > 1.0
    assert family_gaps(images[:, :32, :32], images[:, :32, :32]) is None  # below the statistics' minimum size


def test_mask_lands_on_the_grid_where_its_frame_pixels_land_with_uneven_beams():
    from sonar_realism.evaluate.structure import mask_to_grid
    from sonar_realism.frames import SonarImage, uniform_ranges
    from sonar_realism.models.datasets import to_model_grid

    bearings = np.arcsin(np.linspace(-0.9, 0.9, 256))  # Oculus-like: beams denser at the centre in angle
    image = np.zeros((200, 256), np.float32)
    image[80:120, 20:30] = 1.0  # a bright object near the fan's edge
    frame = SonarImage(image, uniform_ranges(200, 20.0), bearings)
    mask = (image > 0).astype(np.uint8)
    on_grid = mask_to_grid(mask, frame, (128, 128))
    bright = to_model_grid(frame, (128, 128), "frame_max") > 0.5
    assert mask_iou(on_grid, bright.astype(np.float32)) > 0.8
    with pytest.raises(ConfigError, match="mask shape"):
        mask_to_grid(mask[:10], frame, (128, 128))
