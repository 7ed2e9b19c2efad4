"""The paper's realism CNN (Fig. 5): four conv stages and a fully connected head with real/sim outputs.

3@128x128 -> 32@64x64 -> 64@32x32 -> 128@16x16 -> 256@8x8 -> FC(16384 -> 2). Sonar is single-channel, so
the input has one channel instead of the paper's three copies of a colour-mapped image. The score of an
image is the softmax probability of the "real" output (≈1: looks real). Real frames, raw simulation and
translator outputs are compared on exactly the same footing: images arrive as arrays already on the model grid
(`sonar_realism.models.datasets.to_model_grid`, the same preprocessing the cDFCVAE trains on).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from sonar_realism.errors import ConfigError

REAL, SIM = 1, 0  # class indices of the two outputs


@dataclass(frozen=True)
class RealismCNNConfig:
    """Shape and training of the real/sim classifier. Defaults follow Fig. 5 of the paper."""

    grid: tuple[int, int] = (128, 128)
    width: int = 32  # channels of the first stage; each stage doubles it (32, 64, 128, 256 in the paper)
    dropout: float = 0.5  # the real set is small (tens of frames): the 16384-wide head over-fits otherwise
    epochs: int = 25
    batch_size: int = 16
    lr: float = 1e-3
    seed: int = 0

    def validate(self) -> None:
        if any(g < 16 or g % 16 for g in self.grid):
            raise ConfigError(f"grid: each side must be a multiple of 16 and >= 16, got {self.grid}")
        if self.width < 1 or self.epochs < 1 or self.batch_size < 1:
            raise ConfigError("width, epochs and batch_size must be >= 1")
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f"dropout: must be in [0, 1), got {self.dropout}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise ConfigError(f"lr: must be positive, got {self.lr}")


class RealismCNN(nn.Module):
    """Four conv stages (3x3 conv, batch norm, LeakyReLU, 2x2 max-pool) and a linear real/sim head."""

    def __init__(self, config: RealismCNNConfig | None = None) -> None:
        super().__init__()
        self.config = config or RealismCNNConfig()
        self.config.validate()
        widths = [self.config.width * 2 ** i for i in range(4)]
        stages: list[nn.Module] = []
        in_channels = 1
        for out_channels in widths:
            stages += [nn.Conv2d(in_channels, out_channels, 3, padding=1), nn.BatchNorm2d(out_channels),
                       nn.LeakyReLU(0.2), nn.MaxPool2d(2)]
            in_channels = out_channels
        self.features = nn.Sequential(*stages)
        rows, cols = self.config.grid
        self.head = nn.Sequential(nn.Flatten(), nn.Dropout(self.config.dropout),
                                  nn.Linear(widths[-1] * (rows // 16) * (cols // 16), 2))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """Logits [N, 2] (index REAL, SIM) of images [N, 1, rows, cols] in [0, 1]."""
        return self.head(self.features(images))

    def embed(self, images: torch.Tensor) -> torch.Tensor:
        """Penultimate features [N, C]: the last stage's channels averaged over the image (for KID)."""
        return self.features(images).mean(dim=(2, 3))


def _batches(images: np.ndarray, batch_size: int) -> list[torch.Tensor]:
    tensor = torch.from_numpy(np.ascontiguousarray(images, np.float32)).unsqueeze(1)
    return list(torch.split(tensor, batch_size))


def train_classifier(real: np.ndarray, sim: np.ndarray, config: RealismCNNConfig | None = None,
                     progress: Callable[[int, int, float], None] | None = None) -> RealismCNN:
    """Train a RealismCNN to tell `real` [N, rows, cols] from `sim` [M, rows, cols] (both on the grid).

    The classes are weighted by inverse frequency so an unbalanced set does not teach "always sim".
    Beam-mirrored copies are used as augmentation (a scene seen mirrored is still a plausible scene).
    `progress(epoch, epochs, loss)` is called after each epoch.
    """
    config = config or RealismCNNConfig()
    if len(real) == 0 or len(sim) == 0:
        raise ConfigError("realism classifier: needs at least one real and one simulated image")
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    model = RealismCNN(config)
    images = torch.from_numpy(np.concatenate([real, sim]).astype(np.float32)).unsqueeze(1)
    labels = torch.cat([torch.full((len(real),), REAL), torch.full((len(sim),), SIM)])
    weights = torch.tensor([len(labels) / (2.0 * len(sim)), len(labels) / (2.0 * len(real))])
    loss_fn = nn.CrossEntropyLoss(weight=weights)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    for epoch in range(config.epochs):
        model.train()
        order = torch.from_numpy(rng.permutation(len(labels)))
        total = 0.0
        for batch in torch.split(order, config.batch_size):
            x = images[batch]
            flip = torch.from_numpy(rng.random(len(batch)) < 0.5)
            x = torch.where(flip[:, None, None, None], x.flip(-1), x)
            loss = loss_fn(model(x), labels[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += loss.item() * len(batch)
        if progress is not None:
            progress(epoch + 1, config.epochs, total / len(labels))
    recalibrate_batch_norm(model, images, config.batch_size)
    return model


@torch.no_grad()
def recalibrate_batch_norm(model: RealismCNN, images: torch.Tensor, batch_size: int) -> None:
    """Replace the batch-norm running statistics by exact averages over `images` (then switch to eval).

    With tens of images an epoch is a handful of steps, and the exponential running averages are still far
    from the population statistics when training stops: eval-mode outputs would then be miscalibrated.
    """
    norms = [m for m in model.modules() if isinstance(m, nn.BatchNorm2d)]
    for norm in norms:
        norm.reset_running_stats()
        norm.momentum = None  # cumulative average over the batches below
    model.train()
    for batch in torch.split(images, batch_size):
        model.features(batch)
    for norm in norms:
        norm.momentum = 0.1
    model.eval()


@torch.no_grad()
def realism_scores(model: RealismCNN, images: np.ndarray, batch_size: int = 64) -> np.ndarray:
    """The paper's score per image: probability of the "real" output, float64 [N] in [0, 1]."""
    model.eval()
    if len(images) == 0:
        return np.zeros(0)
    probs = [torch.softmax(model(x), dim=1)[:, REAL] for x in _batches(images, batch_size)]
    return torch.cat(probs).double().numpy()


@torch.no_grad()
def embeddings(model: RealismCNN, images: np.ndarray, batch_size: int = 64) -> np.ndarray:
    """Penultimate features of each image, float64 [N, C]."""
    model.eval()
    if len(images) == 0:
        return np.zeros((0, model.config.width * 8))
    return torch.cat([model.embed(x) for x in _batches(images, batch_size)]).double().numpy()
