"""CycleGAN baseline (Zhu et al. 2017) for sim -> real sonar, with the stock architecture and losses.

ResNet generator (7x7 conv, two stride-2 convs, residual blocks, two transposed convs, 7x7 conv, tanh),
70x70 PatchGAN discriminator, least-squares GAN loss, cycle weight 10, identity weight 0.5 (times the
cycle weight), image pools of 50 fakes. Images are single-channel polar grids in [-1, 1]. Checkpoints
are a safetensors file with the four networks and a JSON file beside it (`"model": "cyclegan"`, config,
grid, epoch); `CycleGANTranslator` loads one and translates like the cDFCVAE Translator: on the model grid it was
trained on, or, for one trained on crops (`"grid": null`), each frame whole at its own resolution.
"""

from __future__ import annotations

import json
import random
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file
from torch import nn

from sonar_realism.config import from_dict
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import resample_like, resample_to_grid
from sonar_realism.models.datasets import normalise, to_model_grid
from sonar_realism.models.device import pick_device

CHECKPOINT_KIND = "cyclegan"


@dataclass(frozen=True)
class CycleGANConfig:
    """Network sizes and loss weights; defaults are the stock CycleGAN ones."""

    ngf: int = 64
    ndf: int = 64
    n_blocks: int = 9
    lambda_cycle: float = 10.0
    lambda_identity: float = 0.5  # relative to lambda_cycle, as in the reference code
    pool_size: int = 50
    lr: float = 2e-4
    beta1: float = 0.5
    decay_fraction: float = 0.5  # last fraction of the epochs over which the lr falls linearly to 0

    def validate(self) -> None:
        if min(self.ngf, self.ndf, self.n_blocks) < 1:
            raise ConfigError("ngf, ndf and n_blocks must be >= 1")
        if self.lambda_cycle < 0 or self.lambda_identity < 0 or self.pool_size < 0:
            raise ConfigError("lambda_cycle, lambda_identity and pool_size must be >= 0")
        if not 0.0 < self.lr < 1.0:
            raise ConfigError(f"lr: must be in (0, 1), got {self.lr}")
        if not 0.0 <= self.decay_fraction <= 1.0:
            raise ConfigError(f"decay_fraction: must be in [0, 1], got {self.decay_fraction}")


class ResidualBlock(nn.Module):
    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3), nn.InstanceNorm2d(channels), nn.ReLU(True),
            nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3), nn.InstanceNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class ResnetGenerator(nn.Module):
    """Image [N, 1, H, W] in [-1, 1] -> image of the same shape (H, W multiples of 4)."""

    def __init__(self, ngf: int = 64, n_blocks: int = 9) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.ReflectionPad2d(3), nn.Conv2d(1, ngf, 7), nn.InstanceNorm2d(ngf), nn.ReLU(True)]
        for mult in (1, 2):
            layers += [nn.Conv2d(ngf * mult, ngf * mult * 2, 3, stride=2, padding=1),
                       nn.InstanceNorm2d(ngf * mult * 2), nn.ReLU(True)]
        layers += [ResidualBlock(ngf * 4) for _ in range(n_blocks)]
        for mult in (4, 2):
            layers += [nn.ConvTranspose2d(ngf * mult, ngf * mult // 2, 3, stride=2, padding=1, output_padding=1),
                       nn.InstanceNorm2d(ngf * mult // 2), nn.ReLU(True)]
        layers += [nn.ReflectionPad2d(3), nn.Conv2d(ngf, 1, 7), nn.Tanh()]
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


class PatchDiscriminator(nn.Module):
    """70x70 PatchGAN: one real/fake logit per overlapping 70x70 patch (three stride-2 4x4 convs)."""

    def __init__(self, ndf: int = 64) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.Conv2d(1, ndf, 4, stride=2, padding=1), nn.LeakyReLU(0.2, True)]
        channels = ndf
        for stride, mult in ((2, 2), (2, 4), (1, 8)):
            layers += [nn.Conv2d(channels, ndf * mult, 4, stride=stride, padding=1), nn.InstanceNorm2d(ndf * mult),
                       nn.LeakyReLU(0.2, True)]
            channels = ndf * mult
        layers += [nn.Conv2d(channels, 1, 4, stride=1, padding=1)]
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


def init_weights(module: nn.Module) -> None:
    """N(0, 0.02) for conv weights, as in the reference implementation."""
    if isinstance(module, nn.Conv2d | nn.ConvTranspose2d):
        nn.init.normal_(module.weight, 0.0, 0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)


class ImagePool:
    """History of generated images: once full, half the time the discriminator sees an older fake.

    Showing the discriminator past fakes damps the oscillation between generator and discriminator.
    """

    def __init__(self, size: int, seed: int = 0) -> None:
        self.size = size
        self.images: list[torch.Tensor] = []
        self.random = random.Random(seed)

    def query(self, images: torch.Tensor) -> torch.Tensor:
        if self.size == 0:
            return images
        out = []
        for image in images.detach():
            if len(self.images) < self.size:
                self.images.append(image)
                out.append(image)
            elif self.random.random() < 0.5:
                index = self.random.randrange(self.size)
                out.append(self.images[index])
                self.images[index] = image
            else:
                out.append(image)
        return torch.stack(out)


class CycleGAN(nn.Module):
    """The four networks. Domain A = simulation, B = real: g_ab translates sim -> real."""

    def __init__(self, config: CycleGANConfig | None = None) -> None:
        super().__init__()
        self.config = config or CycleGANConfig()
        self.config.validate()
        self.g_ab = ResnetGenerator(self.config.ngf, self.config.n_blocks)
        self.g_ba = ResnetGenerator(self.config.ngf, self.config.n_blocks)
        self.d_a = PatchDiscriminator(self.config.ndf)
        self.d_b = PatchDiscriminator(self.config.ndf)
        self.apply(init_weights)

    def generator_loss(self, real_a: torch.Tensor, real_b: torch.Tensor) -> tuple[torch.Tensor, dict, tuple]:
        """LSGAN + cycle + identity loss of both generators; also returns the fakes for the discriminators."""
        cfg = self.config
        fake_b = self.g_ab(real_a)
        fake_a = self.g_ba(real_b)
        pred_b, pred_a = self.d_b(fake_b), self.d_a(fake_a)
        gan = nn.functional.mse_loss(pred_b, torch.ones_like(pred_b)) + \
            nn.functional.mse_loss(pred_a, torch.ones_like(pred_a))
        cycle = nn.functional.l1_loss(self.g_ba(fake_b), real_a) + nn.functional.l1_loss(self.g_ab(fake_a), real_b)
        loss = gan + cfg.lambda_cycle * cycle
        terms = {"gan": gan.item(), "cycle": cycle.item()}
        if cfg.lambda_identity > 0:
            identity = nn.functional.l1_loss(self.g_ab(real_b), real_b) + \
                nn.functional.l1_loss(self.g_ba(real_a), real_a)
            loss = loss + cfg.lambda_cycle * cfg.lambda_identity * identity
            terms["identity"] = identity.item()
        return loss, terms, (fake_a, fake_b)

    def discriminator_loss(self, real_a: torch.Tensor, real_b: torch.Tensor, fake_a: torch.Tensor,
                           fake_b: torch.Tensor) -> torch.Tensor:
        """LSGAN loss of both discriminators, each halved as in the reference code."""
        total = torch.zeros(())
        for disc, real, fake in ((self.d_a, real_a, fake_a), (self.d_b, real_b, fake_b)):
            pred_real, pred_fake = disc(real), disc(fake.detach())
            total = total + 0.5 * (nn.functional.mse_loss(pred_real, torch.ones_like(pred_real))
                                   + nn.functional.mse_loss(pred_fake, torch.zeros_like(pred_fake)))
        return total


def resolve_checkpoint(path: str | Path) -> tuple[Path, Path]:
    """(weights .safetensors, config .json) of a checkpoint given as its .safetensors/.json file or its folder."""
    path = Path(path)
    weights = path.with_suffix(".safetensors") if path.suffix in (".safetensors", ".json") \
        else path / "cyclegan.safetensors"
    return weights, weights.with_suffix(".json")


def is_cyclegan_checkpoint(path: str | Path) -> bool:
    """True when the JSON beside the checkpoint says it is a CycleGAN one."""
    _, meta_path = resolve_checkpoint(path)
    try:
        return json.loads(meta_path.read_text()).get("model") == CHECKPOINT_KIND
    except (OSError, ValueError, AttributeError):
        return False


class CycleGANTranslator:
    """Sim -> real with a trained CycleGAN; same `.translate` signature as the cDFCVAE Translator.

    CycleGAN is deterministic, so the n samples of one input are n copies of the same output.
    """

    def __init__(self, generator: ResnetGenerator, grid: tuple[int, int] | None, device: torch.device) -> None:
        self.generator = generator.to(device).eval()
        self.grid = grid
        self.device = device

    @classmethod
    def from_checkpoint(cls, path: str | Path, device: str = "auto") -> CycleGANTranslator:
        weights_path, meta_path = resolve_checkpoint(path)
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, ValueError) as exc:
            raise FormatError(str(meta_path), "json", f"cannot read the checkpoint config: {exc}") from exc
        if meta.get("model") != CHECKPOINT_KIND:
            raise FormatError(str(meta_path), "model", f"expected {CHECKPOINT_KIND!r}, got {meta.get('model')!r}")
        config = from_dict(CycleGANConfig, meta.get("config", {}), where=f"{meta_path}: config")
        try:
            state = load_file(str(weights_path))
        except (OSError, ValueError) as exc:
            raise FormatError(str(weights_path), "safetensors", f"cannot read the weights: {exc}") from exc
        generator = ResnetGenerator(config.ngf, config.n_blocks)
        prefix = "g_ab."
        g_state = {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
        try:
            generator.load_state_dict(g_state)
        except RuntimeError as exc:
            raise FormatError(str(weights_path), "g_ab", f"weights do not fit the config: {exc}") from exc
        return cls(generator, tuple(meta["grid"]) if meta.get("grid") else None, pick_device(device))

    @torch.no_grad()
    def translate(self, frames: Sequence[SonarImage], n: int = 1, temperature: float = 1.0,
                  seed: int | None = None) -> list[SonarImage]:
        """Each frame translated on the model grid and resampled back onto its own geometry (or, with no grid, at
        its own resolution), n copies stacked.

        `temperature` and `seed` are accepted for interface compatibility and have no effect.
        """
        if n < 1:
            raise ConfigError(f"n: must be >= 1, got {n}")
        outputs = []
        for frame in frames:
            base = frame.sample(0) if frame.intensity.ndim == 3 else frame
            meta = {**base.meta, "translator": CHECKPOINT_KIND}
            if self.grid is None:
                fake = self._at_own_resolution(normalise(base, "frame_max"))
                outputs.append(base.replace(intensity=np.repeat(fake[None], n, axis=0), intensity_scale=1.0,
                                            meta=meta))
                continue
            grid = torch.from_numpy(to_model_grid(base, self.grid, "frame_max")[None, None]).to(self.device)
            fake = ((self.generator(grid * 2 - 1) + 1) / 2).clamp(0, 1)[0, 0].cpu().numpy()
            on_grid = resample_to_grid(base, *self.grid) if (base.n_ranges, base.n_beams) != self.grid else base
            result = on_grid.replace(intensity=np.repeat(fake[None], n, axis=0).astype(np.float32),
                                     intensity_scale=1.0, meta=meta)
            if not result.same_geometry(base):
                result = resample_like(result, base)
            outputs.append(result.replace(intensity=np.clip(result.intensity, 0.0, 1.0).astype(np.float32)))
        return outputs

    def _at_own_resolution(self, level: np.ndarray) -> np.ndarray:
        """The generator over a whole frame [R, B] in [0, 1], padded by reflection to its two stride-2 levels."""
        rows, cols = level.shape
        x = torch.from_numpy(np.ascontiguousarray(level, np.float32))[None, None].to(self.device) * 2 - 1
        x = nn.functional.pad(x, (0, -cols % 4, 0, -rows % 4), mode="reflect")
        fake = ((self.generator(x) + 1) / 2).clamp(0, 1)[0, 0, :rows, :cols]
        return fake.cpu().numpy().astype(np.float32)
