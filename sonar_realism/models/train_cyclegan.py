"""Training loop of the CycleGAN baseline: `sonar-realism train --model cyclegan` lands here.

Unpaired: each step draws one batch of simulated and one batch of real images: frames on the model grid
(`--grid`), or, with `--crop N`, N × N crops of the frames at their own resolution, as its authors train it (random
crops of full-resolution images; the generator is fully convolutional and translates whole frames at their own
resolution, where the simulator's own speckle is still there to be mapped). Adam (lr 2e-4, beta1 0.5),
constant lr then linear decay to 0 over the last `decay_fraction` of the epochs. The checkpoint is written
after every `--save-every`-th epoch and after the last (weights of the four networks, optimiser state, JSON with
config, grid, epoch and loss history; each file replaced whole, so a run killed while writing leaves the previous
one), and `--resume` continues where a run stopped. The image pools and random streams are not saved:
a resumed run refills its pools, which changes nothing that matters after a few dozen steps.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from sonar_realism.arguments import json_object
from sonar_realism.config import from_dict, parse_grid, to_dict
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.models.cyclegan import (
    CHECKPOINT_KIND,
    CycleGAN,
    CycleGANConfig,
    ImagePool,
    resolve_checkpoint,
)
from sonar_realism.models.datasets import load_grid_frames, load_native_frames, random_crops
from sonar_realism.models.device import pick_device
from sonar_realism.models.train import write_atomically


def cyclegan_grid(text: str) -> tuple[int, int]:
    """A --grid the generator can take: sides multiples of 4 (two stride-2 levels) and >= 16."""
    rows, cols = parse_grid(text)
    if rows < 16 or cols < 16 or rows % 4 or cols % 4:
        raise ConfigError(f"--grid: sides must be multiples of 4 and >= 16, got {text!r}")
    return rows, cols


def _batches(path: str, flag: str, grid: tuple[int, int] | None, crop: int | None, args: argparse.Namespace
             ) -> tuple[Callable[[np.random.Generator], torch.Tensor], int]:
    """(draw one batch [B, 1, H, W] in tanh's [-1, 1], number of frames). Same preprocessing as the cDFCVAE
    (per-frame max rescale), on the model grid or in crops at the frames' own resolution."""
    if grid is not None:
        images = torch.from_numpy(load_grid_frames(path, grid, "frame_max", args.max_frames).images * 2 - 1)
        return (lambda rng: images[rng.integers(0, len(images), args.batch_size)].unsqueeze(1)), len(images)
    native = load_native_frames(path, "frame_max", args.max_frames)
    smallest = min(native, key=lambda image: min(image.shape))
    if min(smallest.shape) < crop:
        raise ConfigError(f"{flag} {path}: a frame of {smallest.shape[0]} x {smallest.shape[1]} cells is smaller "
                          f"than --crop {crop}")
    return (lambda rng: torch.from_numpy(random_crops(native, args.batch_size, crop, rng) * 2 - 1).unsqueeze(1)), \
        len(native)


def _optimizer_state(optimizer: torch.optim.Optimizer, prefix: str) -> dict[str, torch.Tensor]:
    tensors = {}
    for index, state in optimizer.state_dict()["state"].items():
        for name, value in state.items():
            tensors[f"{prefix}.{index}.{name}"] = torch.as_tensor(value).clone()
    return tensors


def _load_optimizer_state(optimizer: torch.optim.Optimizer, tensors: dict[str, torch.Tensor], prefix: str) -> None:
    state: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        head, index, name = key.rsplit(".", 2)
        if head == prefix:
            state.setdefault(int(index), {})[name] = value
    full = optimizer.state_dict()
    full["state"] = state
    optimizer.load_state_dict(full)


def save_checkpoint(out: Path, model: CycleGAN, opt_g: torch.optim.Optimizer, opt_d: torch.optim.Optimizer,
                    meta: dict[str, Any]) -> Path:
    weights_path, meta_path = resolve_checkpoint(out)
    weights_path.parent.mkdir(parents=True, exist_ok=True)
    state = {**_optimizer_state(opt_g, "opt_g"), **_optimizer_state(opt_d, "opt_d")}
    write_atomically(weights_path, lambda p: save_file(
        {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}, str(p)))
    write_atomically(weights_path.with_suffix(".optim.safetensors"), lambda p: save_file(
        {k: v.cpu().contiguous() for k, v in state.items()}, str(p)))
    write_atomically(meta_path, lambda p: p.write_text(json.dumps(meta, indent=2)))
    return weights_path



def lr_factor(epoch: int, epochs: int, decay_fraction: float) -> float:
    """1 for the constant part, then linear down to 0 at the end of the last epoch."""
    decay_epochs = round(epochs * decay_fraction)
    start = epochs - decay_epochs
    return 1.0 if epoch < start else 1.0 - (epoch - start + 1) / (decay_epochs + 1)


def train(args: argparse.Namespace) -> int:
    """Train (or resume) a CycleGAN sim -> real. See the `train` subcommand for the arguments."""
    if not args.sim:
        raise ConfigError("--sim: the CycleGAN needs simulated frames (it learns sim -> real)")
    if args.save_every < 1:
        raise ConfigError(f"--save-every: need at least 1 epoch, got {args.save_every}")
    if args.crop is not None and args.grid is not None:
        raise ConfigError("--crop trains at the frames' own resolution, --grid on a model grid: give one of them")
    crop = args.crop
    if crop is not None and (crop < 16 or crop % 4):
        raise ConfigError(f"--crop: a multiple of 4 and >= 16 (two stride-2 levels), got {crop}")
    grid = None if crop is not None else cyclegan_grid(args.grid or "128x128")
    overrides = json_object(args.config, "--config", "CycleGANConfig keys") if args.config else {}
    config = from_dict(CycleGANConfig, overrides, where=str(args.config or "config"))
    device = pick_device(args.device)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)

    weights_path, meta_path = resolve_checkpoint(args.out)
    resuming = bool(args.resume) and weights_path.exists()
    meta: dict[str, Any] = {}
    if resuming:
        meta = json.loads(meta_path.read_text())
        if meta.get("model") != CHECKPOINT_KIND:
            raise FormatError(str(meta_path), "model", f"not a {CHECKPOINT_KIND} checkpoint")
        config = from_dict(CycleGANConfig, meta["config"], where=f"{meta_path}: config")
        grid = (int(meta["grid"][0]), int(meta["grid"][1])) if meta.get("grid") else None
        crop = meta.get("crop")
    draw_sim, n_sim = _batches(args.sim, "--sim", grid, crop, args)
    draw_real, n_real = _batches(args.real, "--real", grid, crop, args)
    model = CycleGAN(config).to(device)
    generators = list(model.g_ab.parameters()) + list(model.g_ba.parameters())
    discriminators = list(model.d_a.parameters()) + list(model.d_b.parameters())
    opt_g = torch.optim.Adam(generators, lr=config.lr, betas=(config.beta1, 0.999))
    opt_d = torch.optim.Adam(discriminators, lr=config.lr, betas=(config.beta1, 0.999))
    start_epoch, history = 0, []
    if resuming:
        model.load_state_dict(load_file(str(weights_path)))
        optim = load_file(str(weights_path.with_suffix(".optim.safetensors")))
        _load_optimizer_state(opt_g, optim, "opt_g")
        _load_optimizer_state(opt_d, optim, "opt_d")
        start_epoch, history = int(meta["epoch"]), list(meta.get("history", []))
        print(f"resuming {weights_path} at epoch {start_epoch}", file=sys.stderr)

    pool_a, pool_b = ImagePool(config.pool_size, args.seed), ImagePool(config.pool_size, args.seed + 1)
    steps = max(n_sim, n_real) // args.batch_size or 1
    for epoch in range(start_epoch, args.epochs):
        factor = lr_factor(epoch, args.epochs, config.decay_fraction)
        for opt in (opt_g, opt_d):
            for group in opt.param_groups:
                group["lr"] = config.lr * factor
        sums: dict[str, float] = {}
        began = time.monotonic()
        model.train()
        for step in range(steps):
            real_a = draw_sim(rng).to(device)
            real_b = draw_real(rng).to(device)
            loss_g, terms, (fake_a, fake_b) = model.generator_loss(real_a, real_b)
            opt_g.zero_grad()
            loss_g.backward()
            opt_g.step()
            loss_d = model.discriminator_loss(real_a, real_b, pool_a.query(fake_a), pool_b.query(fake_b))
            opt_d.zero_grad()
            loss_d.backward()
            opt_d.step()
            for key, value in {**terms, "g_total": loss_g.item(), "d_total": loss_d.item()}.items():
                sums[key] = sums.get(key, 0.0) + value
            print(f"\repoch {epoch + 1}/{args.epochs} step {step + 1}/{steps} g {loss_g.item():.3f} "
                  f"d {loss_d.item():.3f}", end="", file=sys.stderr, flush=True)
        history.append({"epoch": epoch + 1, "lr": config.lr * factor, "seconds": time.monotonic() - began,
                        **{k: v / steps for k, v in sums.items()}})
        print(file=sys.stderr)
        if (epoch + 1) % args.save_every and epoch + 1 < args.epochs:
            continue
        save_checkpoint(args.out, model, opt_g, opt_d, {
            "model": CHECKPOINT_KIND, "config": to_dict(config), "grid": list(grid) if grid else None, "crop": crop,
            "epoch": epoch + 1,
            "epochs": args.epochs, "batch_size": args.batch_size, "seed": args.seed, "history": history,
            "real": str(args.real), "sim": str(args.sim), "n_real": n_real, "n_sim": n_sim})
    print(f"checkpoint: {weights_path}", file=sys.stderr)
    return 0
