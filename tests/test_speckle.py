"""The fitted speckle layer: it recovers a known marginal and grain, samples differ, and it travels in checkpoints."""

import cv2
import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.texture import grain
from sonar_realism.models.cdfcvae import CDFCVAE, CDFCVAEConfig, load_checkpoint, save_checkpoint
from sonar_realism.models.speckle import GRAIN_GROUPS, LEVEL_BINS, SpeckleField, group_lag1
from sonar_realism.models.speckle_fit import EXPORT_LEVELS, fit_speckle, top_ratio


def correlated_speckle(shape, n, seed, smear_beams):
    """Gamma (shape 4) intensity speckle made correlated across beams by a [1, smear] box filter."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        raw = rng.gamma(4.0, 0.25, (shape[0], shape[1] + smear_beams - 1))
        smeared = np.stack([raw[:, j:j + shape[1]] for j in range(smear_beams)]).mean(axis=0)
        frames.append(smeared / smeared.mean())
    return frames


def fitted_on(frames, means):
    field = SpeckleField()
    field.set_fit(*fit_speckle(frames, means))
    return field


def test_fit_then_sample_reproduces_the_marginal_and_the_anisotropic_grain():
    ramp = np.linspace(0.2, 0.8, 128)[:, None] * np.ones((1, 96))
    texture = correlated_speckle((128, 96), 12, seed=0, smear_beams=3)
    real = [ramp * t for t in texture]
    field = fitted_on([r / r.max() for r in real], [ramp / (ramp * t).max() for t in texture])
    samples = field.sample(np.repeat(ramp[None], 12, axis=0), torch.Generator().manual_seed(1))
    real_scaled = [r / r.max() for r in real]
    real_grain, sample_grain = grain(real_scaled), grain(list(samples))
    # Smearing across beams correlates neighbouring beams, not neighbouring ranges; the fit must keep that.
    assert real_grain.across_beams > real_grain.along_range + 0.2
    assert sample_grain.across_beams == pytest.approx(real_grain.across_beams, abs=0.1)
    assert sample_grain.along_range == pytest.approx(real_grain.along_range, abs=0.1)
    ratio_real = np.concatenate([(r / ramp).ravel() for r in real_scaled])
    ratio_sample = np.concatenate([(s / ramp).ravel() for s in samples])
    contrast = lambda x: x.std() / x.mean()  # noqa: E731
    assert contrast(ratio_sample) == pytest.approx(contrast(ratio_real), rel=0.15)


def smooth_8_bit_frames(n, seed):
    """Frames over a 60:1 level ramp with smooth log-normal texture (correlated over ~2 bins), exported 8-bit:
    the dark rows tie in long runs, as a real sensor's dark water column does."""
    rng = np.random.default_rng(seed)
    level = np.geomspace(0.01, 0.6, 128)[:, None] * np.ones((1, 96))
    frames = []
    for _ in range(n):
        field = cv2.GaussianBlur(rng.standard_normal((128, 96)).astype(np.float32), (0, 0), 2.0)
        image = level * np.exp(0.5 * field / field.std())
        frames.append(np.round(image / image.max() * EXPORT_LEVELS) / EXPORT_LEVELS)
    return frames


def test_match_grain_brings_each_short_level_groups_neighbour_correlation_to_the_frames():
    frames = smooth_8_bit_frames(6, seed=0)
    means = [cv2.GaussianBlur(frame.astype(np.float32), (0, 0), 4.0) for frame in frames]
    field = fitted_on(frames, means)
    groups = [(field.level_bins(torch.from_numpy(mean)) // (LEVEL_BINS // GRAIN_GROUPS)).numpy() for mean in means]
    real = group_lag1(frames, groups)

    def sampled_lag1(seed):
        generator = torch.Generator().manual_seed(seed)
        return group_lag1([field.sample(mean[None], generator)[0] for mean in means], groups)

    before, before_other_draw = sampled_lag1(0), sampled_lag1(3)
    widths = field.match_grain(frames, means, seed=0)
    short = before < real - 0.02  # the copula's kernel falls short (ties spread at random, clipped spectrum)
    assert short.any()
    np.testing.assert_allclose(sampled_lag1(0)[short], real[short], atol=0.01)
    assert (np.abs(sampled_lag1(3) - real) < np.abs(before_other_draw - real))[short].all()
    assert (widths[short] > 0).all() and (widths[before >= real] == 0).all()  # never sharpened, never widened past


def test_samples_are_max_scaled_8_bit_and_differ_between_draws():
    field = fitted_on(correlated_speckle((64, 64), 4, seed=2, smear_beams=1), [np.ones((64, 64))] * 4)
    mean = np.full((3, 80, 72), 0.5, np.float32)
    samples = field.sample(mean, torch.Generator().manual_seed(0))
    assert samples.shape == (3, 80, 72) and samples.dtype == np.float32
    assert np.allclose(samples.max(axis=(1, 2)), 1.0)
    np.testing.assert_allclose(samples * EXPORT_LEVELS, np.round(samples * EXPORT_LEVELS), atol=1e-4)
    assert np.abs(samples[0] - samples[1]).mean() > 0.02
    again = field.sample(mean, torch.Generator().manual_seed(0))
    np.testing.assert_array_equal(samples, again)


def test_samples_clip_at_full_scale_instead_of_scaling_everything_down():
    field = fitted_on(correlated_speckle((64, 64), 4, seed=2, smear_beams=1), [np.ones((64, 64))] * 4)
    mean = np.full((2, 64, 64), 0.3, np.float32)
    mean[:, :8] = 4.0  # a return far above full scale
    samples = field.sample(mean, torch.Generator().manual_seed(0))
    # the bright rows sit at full scale and the rest keeps its level (speckle about 0.3); scaling by the
    # brightest speckle peak (about 4 x the ratio's upper tail) would have put the rest below 0.08
    assert (samples[:, :8] == 1.0).mean() > 0.9
    assert np.median(samples[:, 8:]) == pytest.approx(0.3, rel=0.25)


def test_the_export_knee_bends_an_overshooting_top_instead_of_piling_pixels_at_full_scale():
    """A mean brighter than the frames' (a simulator's highlights) overshoots full scale under the fitted speckle:
    with a hard clip those pixels pile up at 255, where the sensor's frames have one or two. The matched knee
    bends them below it; around the frames' own means nothing needs bending."""
    rng = np.random.default_rng(0)
    level = np.linspace(0.1, 1.0, 128)[:, None] * np.ones((1, 96))
    frames, means = [], []
    for _ in range(8):
        image = level * np.sqrt(rng.gamma(4.0, 0.25, (128, 96)))
        frames.append((np.round(image / image.max() * EXPORT_LEVELS) / EXPORT_LEVELS).astype(np.float32))
        means.append(cv2.GaussianBlur(frames[-1], (0, 0), 4.0))
    field = SpeckleField()
    field.fit(frames, means)
    assert float(field.export_knee) == 1.0
    brighter = np.stack(means) * 1.2

    def top_and_full_share() -> tuple[float, float]:
        samples = field.sample(brighter, torch.Generator().manual_seed(1))
        return float(np.median([top_ratio(s) for s in samples])), float(np.mean(samples >= 1.0))

    real_top, real_full = float(np.median([top_ratio(f) for f in frames])), float(np.mean(np.stack(frames) >= 1.0))
    clipped_top, clipped_full = top_and_full_share()
    assert clipped_top == 1.0 and clipped_full > 10 * real_full
    knee = field.match_export_knee(frames, list(brighter))
    bent_top, bent_full = top_and_full_share()
    assert knee < 1.0 and float(field.export_knee) == pytest.approx(knee)
    assert real_top < bent_top < clipped_top and bent_full < 2 * real_full


def test_unfitted_field_and_bad_fit_inputs_are_refused():
    with pytest.raises(ConfigError, match="never fitted"):
        SpeckleField().sample(np.ones((1, 64, 64), np.float32), None)
    with pytest.raises(ConfigError, match="one mean field each"):
        fit_speckle([np.ones((64, 64))], [])
    with pytest.raises(ConfigError, match="frame 0"):
        fit_speckle([np.ones((64, 64))], [np.ones((64, 65))])


def test_texture_statistics_travel_in_the_checkpoint(tmp_path):
    config = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8), latent_dim=4, skips=1, output_stride=2,
                           upsample="resize_conv", texture="speckle")
    model = CDFCVAE(config)
    model.texture.set_fit(*fit_speckle(correlated_speckle((64, 64), 3, seed=3, smear_beams=2),
                                       [np.ones((64, 64))] * 3))
    model.texture.export_knee.fill_(0.6)
    path = save_checkpoint(model, tmp_path / "m.safetensors")
    loaded, _ = load_checkpoint(path)
    assert loaded.texture.is_fitted
    for name in ("level_edges", "ratio_quantiles", "kernel", "export_knee"):
        torch.testing.assert_close(getattr(loaded.texture, name), getattr(model.texture, name))
    # a checkpoint fitted before the export knee loads with the hard clip it was fitted with
    tensors = load_file(str(path))
    del tensors["texture.export_knee"]
    save_file(tensors, str(path))
    assert float(load_checkpoint(path)[0].texture.export_knee) == 1.0
    # The decoder stops at half the grid and is resized up: the output keeps the grid's shape.
    assert loaded(torch.rand(2, 1, 32, 32))[0].shape == (2, 1, 32, 32)


def test_output_stride_must_leave_the_decoder_a_level_and_fit_the_skips():
    with pytest.raises(ConfigError, match="output_stride"):
        CDFCVAEConfig(widths=(4, 8, 8), output_stride=3).validate()
    with pytest.raises(ConfigError, match="skips"):
        CDFCVAEConfig(widths=(4, 8, 8), skips=2, output_stride=2).validate()


def test_grain_is_fitted_per_level_group():
    """Dark pixels smeared along range (a water column's per-beam stripes), bright ones white: one kernel for
    all levels would give both the average; the fit keeps each level's own grain."""
    rng = np.random.default_rng(4)
    level = np.where(np.arange(96)[None, :] < 48, 0.15, 0.8) * np.ones((128, 1))
    frames, means = [], []
    for _ in range(10):
        white = rng.gamma(4.0, 0.25, (128 + 5, 96))
        smeared = np.stack([white[k:k + 128] for k in range(6)]).mean(axis=0)
        ratio = np.where(level < 0.5, smeared / smeared.mean(), white[:128] / white.mean())
        image = level * ratio
        frames.append(np.round(image / image.max() * EXPORT_LEVELS) / EXPORT_LEVELS)  # exported as 8-bit
        means.append(level / image.max())
    field = fitted_on(frames, means)
    samples = field.sample(np.stack(means[:8]).astype(np.float32), torch.Generator().manual_seed(2))

    def along_range(images, columns):
        values = [np.corrcoef(image[:-1, columns].ravel(), image[1:, columns].ravel())[0, 1] for image in images]
        return float(np.mean(values))

    dark, bright = slice(0, 48), slice(48, 96)
    assert along_range(frames, dark) > 0.6 and abs(along_range(frames, bright)) < 0.1
    assert along_range(samples, dark) == pytest.approx(along_range(frames, dark), abs=0.12)
    assert along_range(samples, bright) == pytest.approx(along_range(frames, bright), abs=0.12)
