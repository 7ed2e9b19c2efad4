"""Texture learned against the sensor: a small convolutional generator trained adversarially on real frames.

Why not the parametric speckle of models/speckle.py alone: a Gaussian-copula field with the sensor's marginal
per level and its grain is told from the sensor's texture by a patch classifier at accuracy 1.00 even around a
frame's own local mean, and so is the same field with the frame's own full power spectrum (phase-randomised):
the tell is in the texture's higher-order structure (smooth blobs with soft edges where the copula draws
isolated dark holes, streaks across beams, an asymmetric response along range; docs/RESULTS.md).

The generator G maps a mean field M (the level a translation or a simulator gives) plus white noise at five
scales (the pixel, and 1/2 to 1/16 of the grid: grain and blobs) and the range position to a log ratio; the
sample is I = M · exp(G), clipped at full scale and exported as the sensor exports (scaled to its maximum,
8-bit). It is fully convolutional, so it runs on any grid at the sensor's own resolution.

Fitting (`LearnedTexture.fit`) on real frames scaled to their maximum and a mean field of each (the same pairs
SpeckleField.fit takes), and, for a translator, on the mean fields it decodes from simulated frames (unpaired:
the texture must learn what the simulator's scene lacks, not only what lies around a real frame's own mean):
crops; a patch critic with the texture two-sample test's architecture
(evaluate/two_sample.py) sees 32 x 32 patches with their means removed, as the test does; the generator gets
the critic's non-saturating loss plus the distance between real and generated log-ratio quantiles in each
level bin of M (so the marginal per level, which the critic sees only through patch shapes, holds from the
start) and between their neighbour correlations along range and across beams, each crop less its own local box
mean as the grain statistic takes it (without this term the critic left the samples' lag-1 correlation along
range at 0.15 against the sensor's 0.30). Quantisation
to 8 bits is passed straight through, so the critic cannot key on it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.statistics import StatisticsConfig
from sonar_realism.evaluate.two_sample import patch_classifier
from sonar_realism.models.device import one_thread
from sonar_realism.models.speckle import export_like_sensor
from sonar_realism.models.speckle_fit import EXPORT_LEVELS, LEVEL_BINS, MEAN_FLOOR, level_edges
from sonar_realism.parallel import parallel_map

FULL_CHANNELS = 12  # at the sensor's resolution: the grain and the 8-bit steps live there
HALF_CHANNELS = 16  # at half resolution each way: the blobs, fades and streaks; a quarter of the cost a channel
HALF_DILATIONS = (1, 2, 4, 2)  # with the full-resolution layers, a receptive field of about 70 bins
NOISE_SCALES = (2, 4, 8, 16)  # white noise on grids this much coarser than the frame, drawn into the half level
LEVEL_FLOOR = 1.0 / EXPORT_LEVELS  # the generator sees log levels from one 8-bit step up
CRITIC_PATCH = 32  # the texture two-sample test's patch
MARGINAL_QUANTILES = 33  # log-ratio quantiles compared per level bin, 0.01 to 0.99
GRAIN_DETREND = StatisticsConfig().detrend  # the box the grain statistic removes the scene with
MARGINAL_MIN_PIXELS = 200  # a level bin with fewer pixels in a batch is left out of the marginal loss


@dataclass(frozen=True)
class TextureFitConfig:
    """The adversarial fit's schedule (the generator's architecture is fixed: GENERATOR_CHANNELS, DILATIONS)."""

    steps: int = 4000
    crop: int = 64
    batch: int = 16
    generator_lr: float = 2e-4
    critic_lr: float = 1e-3
    critic_width: int = 32
    marginal_weight: float = 1.0
    grain_weight: float = 10.0
    # The fitted generator is an exponential moving average of its weights over the steps (0: the last step's):
    # an adversarial fit ends wherever its last oscillation left it. On two paired Oculus fits the average's
    # texture test read 0.86 and 0.76 where the same fits' last steps read 0.94 and 0.79 (docs/RESULTS.md).
    ema_decay: float = 0.999

    def validate(self) -> None:
        if self.crop < CRITIC_PATCH or self.crop % CRITIC_PATCH:
            raise ConfigError(f"texture_fit.crop {self.crop}: a multiple of the critic's patch ({CRITIC_PATCH})")
        if self.steps < 1 or self.batch < 1 or self.generator_lr <= 0 or self.critic_lr <= 0 or \
                self.critic_width < 1 or self.marginal_weight < 0 or self.grain_weight < 0 or \
                not 0 <= self.ema_decay < 1:
            raise ConfigError(f"texture_fit: steps >= 1, batch >= 1, positive rates and critic_width, "
                              f"marginal_weight and grain_weight >= 0 and ema_decay in [0, 1) are needed, got {self}")


DEFAULT_FIT = TextureFitConfig()


class TextureGenerator(nn.Module):
    """(log level, range position, multi-scale noise) -> log ratio.

    A full-resolution layer sees the level, the range position and pixel noise; a strided layer takes it to
    half resolution, where coarser noise joins and residual dilated 3 x 3 layers shape the texture's blobs; the
    result is upsampled, fused with the full-resolution features and refined there. Most of the work runs at
    a quarter of the pixels: at 512 x 256 it keeps the translator above the sensor's ping rate on two cores
    (the previous generator, 7 layers of 24 channels at full resolution, cost about 10 times as much;
    docs/RESULTS.md)."""

    def __init__(self) -> None:
        super().__init__()
        self.inp = nn.Conv2d(3, FULL_CHANNELS, 3, padding=1)
        self.down = nn.Conv2d(FULL_CHANNELS, HALF_CHANNELS, 3, stride=2, padding=1)
        self.mix = nn.Conv2d(HALF_CHANNELS + len(NOISE_SCALES), HALF_CHANNELS, 3, padding=1)
        self.body = nn.ModuleList([nn.Conv2d(HALF_CHANNELS, HALF_CHANNELS, 3, padding=d, dilation=d)
                                   for d in HALF_DILATIONS])
        self.lift = nn.Conv2d(HALF_CHANNELS, FULL_CHANNELS, 1)  # at half resolution, before upsampling
        self.fuse = nn.Conv2d(FULL_CHANNELS, FULL_CHANNELS, 1)
        self.refine = nn.Conv2d(FULL_CHANNELS, FULL_CHANNELS, 3, padding=1)
        self.out = nn.Conv2d(FULL_CHANNELS, 1, 3, padding=1)

    def forward(self, mean: torch.Tensor, range_position: torch.Tensor,
                generator: torch.Generator | None = None) -> torch.Tensor:
        """mean, range_position: [n, 1, H, W] -> log ratio [n, 1, H, W]."""
        n, _, rows, cols = mean.shape
        pixel_noise = torch.randn((n, 1, rows, cols), generator=generator).to(mean.device)
        level = torch.log(mean.clamp_min(LEVEL_FLOOR)) / 2 + 1  # about [-1, 1] over the 8-bit levels
        full = F.leaky_relu(self.inp(torch.cat([level, range_position, pixel_noise], 1)), 0.2, inplace=True)
        half = F.leaky_relu(self.down(full), 0.2, inplace=True)
        half_size = half.shape[-2:]
        noises = []
        for factor in NOISE_SCALES:
            noise = torch.randn((n, 1, -(-rows // factor), -(-cols // factor)), generator=generator).to(mean.device)
            noises.append(noise if noise.shape[-2:] == half_size else
                          F.interpolate(noise, size=half_size, mode="bilinear", align_corners=False))
        half = F.leaky_relu(self.mix(torch.cat([half, *noises], 1)), 0.2, inplace=True)
        for conv in self.body:
            half = half + F.leaky_relu(conv(half), 0.2, inplace=True)
        up = F.interpolate(self.lift(half), size=(rows, cols), mode="bilinear", align_corners=False)
        x = F.leaky_relu(self.fuse(full) + up, 0.2, inplace=True)
        x = x + F.leaky_relu(self.refine(x), 0.2, inplace=True)
        return self.out(x)


def range_position(rows: int, cols: int, first_row: int = 0, total_rows: int | None = None) -> torch.Tensor:
    """[1, 1, rows, cols]: each row's place in its frame's range, -1 (nearest) to 1 (farthest)."""
    total = rows if total_rows is None else total_rows
    place = (torch.arange(first_row, first_row + rows, dtype=torch.float32) / max(total - 1, 1)) * 2 - 1
    return place[None, None, :, None].expand(1, 1, rows, cols)


@dataclass(frozen=True)
class TextureFitRecord:
    steps: int
    seconds: float
    critic_loss: float  # last 100 steps' mean; 2 ln 2 = 1.386 is a critic at chance
    marginal_loss: float


class LearnedTexture(nn.Module):
    """The generators' weights travel in the checkpoint; `fit` trains them, `sample` draws textured frames.

    With more than one generator the texture is a mixture: each is fitted on its own seed, and a batch's samples
    take them in turn from a random start (n samples of one frame meet min(n, generators) of them). One adversarial
    fit of the recipe lands anywhere from 0.76 to 0.94 on the held-out texture test (docs/RESULTS.md); a mixture
    draws from several of those ends instead of betting on one, and which ends are good cannot be told on the
    training side."""

    def __init__(self, generators: int = 1) -> None:
        super().__init__()
        if generators < 1:
            raise ConfigError(f"learned texture: generators {generators}; need at least 1")
        # channels-last: at the sensor's resolution a few channels per pixel run about 4 times as fast this way
        self.generators = nn.ModuleList([TextureGenerator().to(memory_format=torch.channels_last)
                                         for _ in range(generators)])
        self.register_buffer("fitted", torch.zeros(()))

    @property
    def is_fitted(self) -> bool:
        return bool(self.fitted.item())

    def _speckled(self, mean: torch.Tensor, position: torch.Tensor,
                  generator: torch.Generator | None) -> torch.Tensor:
        """M · exp(G_k(M)), each sample's G_k taken in turn from a random start, unclipped: [n, 1, H, W]."""
        count = len(self.generators)
        if count == 1:
            return _speckled_by(self.generators[0], mean, position, generator)
        start = int(torch.randint(count, (1,), generator=generator))
        picks = (start + torch.arange(len(mean))) % count
        speckled = torch.empty_like(mean)
        for k in picks.unique().tolist():
            rows = (picks == k).nonzero()[:, 0].to(mean.device)
            speckled[rows] = _speckled_by(self.generators[k], mean[rows], position[rows], generator)
        return speckled

    @torch.no_grad()
    def sample(self, mean: np.ndarray, generator: torch.Generator | None,
               row_gain: np.ndarray | None = None, knee: float | None = None) -> np.ndarray:
        """Textured, max-scaled, 8-bit samples float32 [n, H, W] in [0, 1] of mean fields [n, H, W] in full-scale
        units; `row_gain` [H] and the export's `knee` as `SpeckleField.sample` takes them (None: the hard clip
        the generator was fitted under)."""
        if not self.is_fitted:
            raise ConfigError("texture: this checkpoint's learned texture was never fitted")
        device = self.fitted.device
        mean_t = torch.from_numpy(np.ascontiguousarray(mean, np.float32))[:, None].to(device)
        position = range_position(*mean_t.shape[-2:]).to(device).expand(mean_t.shape[0], -1, -1, -1)
        return export_like_sensor(self._speckled(mean_t, position, generator)[:, 0].float().cpu(), row_gain,
                                  1.0 if knee is None else knee)

    def fit(self, images: list[np.ndarray], means: list[np.ndarray], seed: int = 0,
            schedule: TextureFitConfig = DEFAULT_FIT, progress: bool = False,
            draw_on: list[np.ndarray] | None = None, workers: int | None = None
            ) -> list[TextureFitRecord]:
        """Train each generator (the k-th from `seed` + k) against a patch critic on real frames (scaled to their
        maximum) and a mean field of each, on the same grid at the sensor's resolution.

        On the CPU each generator is fitted on one thread (`one_thread`: the same frames and seed give the same
        generator on any machine; a fit on two threads once came out at 1.00 on the texture test where its
        one-thread refit read 0.83), the generators side by side in `workers` forked processes (None: one per
        available core), so a mixture of four costs two single-thread fits' time on two cores.

        `draw_on`: the mean fields the texture will be drawn on in use, when they are not the real frames' own
        (None: `means`), e.g. the translator's decoded means of simulated frames. The generator then learns on
        those, unpaired: the critic compares its output on them with the real frames, the marginal term each
        side's ratio to its own mean field, the grain term each side's detrended grain. Fitted around the real
        frames' own means, the texture learns nothing of the scene it will sit on; on the simulator's, it learns
        to turn that scene's soft blotches into the sensor's texture (docs/RESULTS.md).

        Returns each generator's record, in order."""
        drawn_on = means if draw_on is None else draw_on
        if not images or len(images) != len(means) or not drawn_on:
            raise ConfigError(f"learned texture fit: need real frames and one mean field each, got {len(images)} "
                              f"and {len(means)}, and mean fields to draw on (got {len(drawn_on)})")
        schedule.validate()
        crop = schedule.crop
        for index, (image, mean) in enumerate(zip(images, means, strict=True)):
            if image.shape != mean.shape or image.ndim != 2 or min(image.shape) < crop:
                raise ConfigError(f"learned texture fit: frame {index} has shape {image.shape} and mean "
                                  f"{mean.shape}; need equal 2-D shapes with sides >= {crop}")
        for index, mean in enumerate(drawn_on):
            if mean.ndim != 2 or min(mean.shape) < crop:
                raise ConfigError(f"learned texture fit: mean field {index} to draw on has shape {mean.shape}; "
                                  f"need 2-D with sides >= {crop}")
        edges = torch.from_numpy(level_edges(np.concatenate([np.maximum(m, MEAN_FLOOR).ravel() for m in means]))
                                 .astype(np.float32)).to(self.fitted.device)

        def fit_one(k: int) -> tuple[dict[str, torch.Tensor], TextureFitRecord]:
            with one_thread():
                record = _fit_generator(self.generators[k], images, means, draw_on, edges, seed + k, schedule,
                                        progress, f"texture generator {k}" if len(self.generators) > 1 else "texture")
            return {key: value.clone() for key, value in self.generators[k].state_dict().items()}, record

        on_cpu = self.fitted.device.type == "cpu"
        if workers is None:  # the cores this process may use (sched_getaffinity is Linux's; elsewhere all of them)
            workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        fitted = parallel_map(fit_one, range(len(self.generators)), workers if on_cpu else 1)
        for texture_generator, (state, _) in zip(self.generators, fitted, strict=True):
            texture_generator.load_state_dict(state)  # a forked worker fitted a copy
            texture_generator.eval()
        self.fitted.fill_(1.0)
        return [record for _, record in fitted]


def mixture_of(textures: Sequence[LearnedTexture]) -> LearnedTexture:
    """One texture drawing from every generator of the fitted `textures`, in their order: the same mixture
    `fit` makes, with its generators fitted apart (in other runs, say)."""
    if not textures or not all(texture.is_fitted for texture in textures):
        raise ConfigError("texture mixture: needs one or more fitted learned textures")
    sources = [texture_generator for texture in textures for texture_generator in texture.generators]
    mixed = LearnedTexture(len(sources))
    for target, source in zip(mixed.generators, sources, strict=True):
        target.load_state_dict(source.state_dict())
    mixed.fitted.fill_(1.0)
    return mixed.eval()


def current_state(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    """A learned texture's tensors (under `prefix`) as this version names them: a texture saved before mixtures
    held one generator, `generator.*`, which is the mixture's first, `generators.0.*`."""
    old = f"{prefix}generator."
    return {(f"{prefix}generators.0.{key[len(old):]}" if key.startswith(old) else key): value
            for key, value in tensors.items()}


def generator_count(tensors: dict[str, torch.Tensor]) -> int:
    """How many generators a learned texture's own tensors (as `current_state` names them) hold."""
    return len({key.split(".", 2)[1] for key in tensors if key.startswith("generators.")})


def _speckled_by(texture_generator: TextureGenerator, mean: torch.Tensor, position: torch.Tensor,
                 generator: torch.Generator | None) -> torch.Tensor:
    return mean * torch.exp(texture_generator(mean, position, generator))


def _textured(texture_generator: TextureGenerator, mean: torch.Tensor, position: torch.Tensor) -> torch.Tensor:
    """M · exp(G(M)), clipped at full scale, 8-bit steps passed straight through: what the critic sees."""
    image = _speckled_by(texture_generator, mean, position, None).clamp(max=1.0)
    stepped = torch.round(image * EXPORT_LEVELS) / EXPORT_LEVELS
    return image + (stepped - image).detach()


def _fit_generator(texture_generator: TextureGenerator, images: list[np.ndarray], means: list[np.ndarray],
                   draw_on: list[np.ndarray] | None, edges: torch.Tensor, seed: int, schedule: TextureFitConfig,
                   progress: bool, name: str) -> TextureFitRecord:
    """One generator's adversarial fit (`LearnedTexture.fit`); it ends holding its weights' moving average."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    device = edges.device
    crop = schedule.crop
    critic = patch_classifier(schedule.critic_width).to(device)
    # the fit trains its generator whatever the caller froze: `train` freezes the whole model between its cycles,
    # and a frozen generator let the critic win at once while its weights stayed at their initial values
    texture_generator.requires_grad_(True)
    generator_opt = torch.optim.Adam(texture_generator.parameters(), schedule.generator_lr, betas=(0.5, 0.99))
    critic_opt = torch.optim.Adam(critic.parameters(), schedule.critic_lr, betas=(0.5, 0.99))
    probabilities = torch.linspace(0.01, 0.99, MARGINAL_QUANTILES, device=device)
    critic_losses: list[float] = []
    marginal_losses: list[float] = []
    averaged = [parameter.detach().clone() for parameter in texture_generator.parameters()]
    start = time.perf_counter()
    texture_generator.train()
    for step in range(schedule.steps):
        real, real_mean, real_position = (t.to(device) for t in _crops((images, means), crop, schedule.batch, rng))
        if draw_on is None:
            mean, position = real_mean, real_position
        else:
            mean, position = (t.to(device) for t in _crops((draw_on,), crop, schedule.batch, rng))
        fake = _textured(texture_generator, mean, position)
        real_patches = _mean_removed_patches(real)
        both = torch.cat([real_patches, _mean_removed_patches(fake.detach())])
        flip = (torch.rand(len(both)) < 0.5).to(device)  # the test flips across beams at random too
        logits = critic(torch.where(flip[:, None, None, None], both.flip(-1), both))[:, 0]
        critic_loss = F.softplus(-logits[:len(real_patches)]).mean() + F.softplus(logits[len(real_patches):]).mean()
        critic_opt.zero_grad()
        critic_loss.backward()
        critic_opt.step()
        logits = critic(torch.cat([real_patches, _mean_removed_patches(fake)]))[len(real_patches):, 0]
        marginal = _marginal_loss(real, real_mean, fake, mean, edges, probabilities)
        grain_gap = (_lag1(_detrended(real)) - _lag1(_detrended(fake))).square().sum()
        loss = F.softplus(-logits).mean() + schedule.marginal_weight * marginal + schedule.grain_weight * grain_gap
        generator_opt.zero_grad()
        loss.backward()
        generator_opt.step()
        # the usual warm-up: early steps, far from where the fit settles, are forgotten fast
        decay = min(schedule.ema_decay, (1 + step) / (10 + step))
        with torch.no_grad():
            for average, parameter in zip(averaged, texture_generator.parameters(), strict=True):
                average.lerp_(parameter, 1 - decay)
        critic_losses.append(critic_loss.item())
        marginal_losses.append(marginal.item())
        if progress and step % 100 == 0:
            print(f"{name} step {step}: critic {np.mean(critic_losses[-100:]):.3f}, marginal "
                  f"{np.mean(marginal_losses[-100:]):.3f}", flush=True)
    with torch.no_grad():
        for average, parameter in zip(averaged, texture_generator.parameters(), strict=True):
            parameter.copy_(average)
    texture_generator.eval()
    return TextureFitRecord(steps=schedule.steps, seconds=time.perf_counter() - start,
                            critic_loss=float(np.mean(critic_losses[-100:])),
                            marginal_loss=float(np.mean(marginal_losses[-100:])))


def _marginal_loss(real: torch.Tensor, real_mean: torch.Tensor, fake: torch.Tensor, fake_mean: torch.Tensor,
                   edges: torch.Tensor, probabilities: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference of log-ratio quantiles, real around its mean against generated around its own,
    over the level bins of the mean fields (a bin either side leaves out when it has too few pixels)."""
    real_log = torch.log((real / real_mean.clamp_min(LEVEL_FLOOR)).clamp_min(LEVEL_FLOOR))
    fake_log = torch.log((fake / fake_mean.clamp_min(LEVEL_FLOOR)).clamp_min(LEVEL_FLOOR))
    real_bins, fake_bins = torch.bucketize(real_mean, edges), torch.bucketize(fake_mean, edges)
    total = torch.zeros((), device=real.device)
    for level in range(LEVEL_BINS):
        real_inside, fake_inside = real_bins == level, fake_bins == level
        if int(real_inside.sum()) < MARGINAL_MIN_PIXELS or int(fake_inside.sum()) < MARGINAL_MIN_PIXELS:
            continue
        total = total + (torch.quantile(real_log[real_inside], probabilities)
                         - torch.quantile(fake_log[fake_inside], probabilities)).abs().mean()
    return total


def _crops(aligned: Sequence[list[np.ndarray]], crop: int, batch: int, rng: np.random.Generator
           ) -> list[torch.Tensor]:
    """`batch` random crops taken at the same places of each list of equally shaped frames ([b, 1, crop, crop]
    each), then their range position."""
    picked: list[list[np.ndarray]] = [[] for _ in aligned]
    positions = []
    for _ in range(batch):
        k = int(rng.integers(len(aligned[0])))
        rows, cols = aligned[0][k].shape
        r0, c0 = int(rng.integers(0, rows - crop + 1)), int(rng.integers(0, cols - crop + 1))
        for frames, out in zip(aligned, picked, strict=True):
            out.append(frames[k][r0:r0 + crop, c0:c0 + crop])
        positions.append(range_position(crop, crop, r0, rows)[0, 0])

    def stacked(arrays: list) -> torch.Tensor:
        return torch.from_numpy(np.stack([np.asarray(a, np.float32) for a in arrays]))[:, None]

    return [*(stacked(out) for out in picked), stacked(positions)]


def _lag1(residual: torch.Tensor) -> torch.Tensor:
    """[2]: correlation of neighbouring residuals along range and across beams, over a batch [n, 1, H, W]."""
    energy = residual.square().sum().clamp_min(1e-12)
    return torch.stack([(residual[:, :, 1:] * residual[:, :, :-1]).sum() / energy,
                        (residual[..., 1:] * residual[..., :-1]).sum() / energy])


def _detrended(images: torch.Tensor) -> torch.Tensor:
    """Each frame less its own GRAIN_DETREND x GRAIN_DETREND box mean, as the grain statistic detrends
    (evaluate/statistics.py): the generator's residual around the mean field it was given would also count the
    blobs it adds to a smooth simulated scene as grain, and trade them for a finer grain (along range 0.62 of
    the sensor's, docs/RESULTS.md)."""
    pad = GRAIN_DETREND // 2
    padded = F.pad(images, (pad, pad, pad, pad), mode="reflect")
    return images - F.avg_pool2d(padded, GRAIN_DETREND, stride=1)


def _mean_removed_patches(images: torch.Tensor) -> torch.Tensor:
    """The critic's view, as the texture test's: [n, 1, CRITIC_PATCH, CRITIC_PATCH] tiles, each less its mean."""
    patches = images.unfold(2, CRITIC_PATCH, CRITIC_PATCH).unfold(3, CRITIC_PATCH, CRITIC_PATCH)
    patches = patches.reshape(-1, 1, CRITIC_PATCH, CRITIC_PATCH)
    return patches - patches.mean(dim=(2, 3), keepdim=True)
