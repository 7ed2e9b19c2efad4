"""Training the cDFCVAE in two cycles (docs/method.md), and the `sonar-realism train` command.

Cycle 1: the real encoder and the decoder learn to reconstruct real frames (perceptual loss + β·KL).
Cycle 2: starting from cycle 1's best weights, the simulated-frame encoder (a copy of the real one) learns
to reconstruct simulated frames through the decoder, which stays frozen by default so it keeps the real
texture. Both cycles stop early when the validation loss has not improved for `patience` epochs, and the
best epoch's weights are kept.

A run folder holds everything needed to resume after an interruption (`--resume`): `state.safetensors`
(weights, best weights, Adam moments, torch RNG) and `state.json` (cycle, epoch, early-stopping records,
loss history, numpy RNG), written atomically after every epoch. Finished runs also hold `model.safetensors`
+ `model.json` (the checkpoint `translate` loads), `cycle1.safetensors`, `early_stopping.json`,
`config.json` and `loss_curves.png`.

GPU: CUDA runs use bf16 autocast and channels_last; `torchrun --nproc_per_node=K -m sonar_realism.cli train`
trains with DistributedDataParallel (each rank takes every K-th batch item; rank 0 writes the files).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn
from tqdm import tqdm

from sonar_realism.arguments import json_object, non_negative_int
from sonar_realism.config import from_dict, parse_grid, to_dict
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.frames import SonarImage
from sonar_realism.io import read_frames
from sonar_realism.models.cdfcvae import (
    CDFCVAE,
    CDFCVAEConfig,
    PerceptualConfig,
    PerceptualLoss,
    load_checkpoint,
    round_to_half,
    save_checkpoint,
)
from sonar_realism.models.datasets import (
    GridFrames,
    Normalisation,
    batches,
    from_model_grid,
    load_grid_frames,
    normalise,
    recording_of,
    recording_sources,
    split_by_recording,
    to_model_grid,
)
from sonar_realism.models.device import pick_device
from sonar_realism.models.learned_texture import DEFAULT_FIT, LearnedTexture, TextureFitConfig

STATE_FORMAT = "sonar_realism.cdfcvae.train_state"
TEXTURE_FIT_FRAMES = 96  # evenly spaced over the training recordings: enough for 129 quantiles in 8 level bins
# The speckle is fitted around the decoder's output as the translator draws it by default (temperature 1):
# latent draws come out darker than the posterior mean (about 14 % in the mean on the calibrated Oculus sim),
# and a table fitted around the mean darkened every translated frame by that much (docs/RESULTS.md).
TEXTURE_FIT_TEMPERATURE = 1.0


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run (CLI flags override the matching keys)."""

    model: CDFCVAEConfig = field(default_factory=CDFCVAEConfig)
    perceptual: PerceptualConfig = field(default_factory=PerceptualConfig)
    texture_fit: TextureFitConfig = field(default_factory=TextureFitConfig)  # model.texture "learned" only
    learning_rate: float = 5e-4
    adam_betas: tuple[float, float] = (0.5, 0.999)
    batch_size: int = 16
    epochs1: int = 80
    epochs2: int = 60
    patience: int = 10
    min_improvement: float = 1e-3  # relative drop of the validation loss that counts as progress
    normalisation: Normalisation = "frame_max"
    real_val_recordings: tuple[str, ...] = ()
    # Train on these real recordings only (empty: all); the others stay unseen, for evaluation.
    real_recordings: tuple[str, ...] = ()
    val_fraction: float = 0.2
    flip_beams: bool = True
    cycle2: Literal["second_encoder", "shared_encoder"] = "second_encoder"
    cycle2_train_decoder: bool = False
    max_frames: int | None = None
    seed: int = 0
    half_precision_checkpoint: bool = True

    def validate(self) -> None:
        self.model.validate()
        self.perceptual.validate()
        self.texture_fit.validate()
        if not 0 < self.learning_rate < math.inf:
            raise ConfigError(f"learning_rate: must be a positive number, got {self.learning_rate}")
        if self.batch_size < 1 or self.patience < 1:
            raise ConfigError(f"batch_size and patience must be positive, got {self.batch_size} and {self.patience}")
        if len(self.adam_betas) != 2 or not all(0.0 <= beta < 1.0 for beta in self.adam_betas):
            raise ConfigError(f"adam_betas: two numbers in [0, 1), got {list(self.adam_betas)}")
        if self.seed < 0:
            raise ConfigError(f"seed: must be 0 or more, got {self.seed}")
        if self.epochs1 < 0 or self.epochs2 < 0:
            raise ConfigError("epochs1 and epochs2 must be >= 0")
        if not 0.0 < self.val_fraction < 1.0:
            raise ConfigError(f"val_fraction {self.val_fraction}: in (0, 1)")
        if self.max_frames is not None and self.max_frames < 2:
            raise ConfigError("max_frames must be >= 2 (one for training, one for validation)")


# --- early stopping -------------------------------------------------------------------------------------------------

@dataclass
class EarlyStopping:
    """The record of one cycle: best validation loss, when, and why training stopped."""

    patience: int
    min_improvement: float
    best_loss: float = float("inf")
    best_epoch: int = 0
    epochs_done: int = 0
    stale_epochs: int = 0
    stopped_reason: str = ""

    def update(self, val_loss: float) -> bool:
        """Record one finished epoch; True when it is the best so far."""
        self.epochs_done += 1
        improved = val_loss < self.best_loss * (1.0 - self.min_improvement) or self.best_epoch == 0
        if improved:
            self.best_loss, self.best_epoch, self.stale_epochs = val_loss, self.epochs_done, 0
        else:
            self.stale_epochs += 1
            if self.stale_epochs >= self.patience:
                self.stopped_reason = f"no improvement for {self.patience} epochs"
        return improved

    @property
    def stopped(self) -> bool:
        return bool(self.stopped_reason)


# --- one run -------------------------------------------------------------------------------------------------------

@dataclass
class Data:
    train: GridFrames
    val: GridFrames
    split: str


def load_data(path: str | Path, cfg: TrainConfig, by_recording: bool) -> Data:
    keep_some = by_recording and bool(cfg.real_recordings)
    frames = load_grid_frames(path, cfg.model.grid, cfg.normalisation, None if keep_some else cfg.max_frames)
    if keep_some:
        kept = np.flatnonzero(np.isin(np.asarray(frames.recordings), cfg.real_recordings))
        if kept.size == 0:
            raise ConfigError(f"real_recordings {list(cfg.real_recordings)}: none of them is in {path} (it has "
                              f"{', '.join(sorted(set(frames.recordings)))})")
        frames = frames.subset(kept[:cfg.max_frames])
    if len(frames) < 2:
        raise ConfigError(f"{path}: need at least 2 frames (training and validation), found {len(frames)}")
    if by_recording:
        train_idx, val_idx, how = split_by_recording(frames, cfg.real_val_recordings, cfg.val_fraction)
    else:
        # Simulated frames are independent renders, so a seeded random split is fair.
        order = np.random.default_rng(cfg.seed).permutation(len(frames))
        n_val = max(1, int(round(cfg.val_fraction * len(frames))))
        val_idx, train_idx, how = np.sort(order[:n_val]), np.sort(order[n_val:]), "random (seeded)"
    if len(train_idx) == 0 or len(val_idx) == 0:
        raise ConfigError(f"{path}: the split left no training or no validation frames ({how})")
    return Data(frames.subset(train_idx), frames.subset(val_idx), how)


class Trainer:
    """Runs (or resumes) the two cycles in a run folder."""

    def __init__(self, cfg: TrainConfig, out: str | Path, device: torch.device, progress: bool = True) -> None:
        cfg.validate()
        self.cfg, self.out, self.device, self.progress = cfg, Path(out), device, progress
        self.rank, self.world = int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))
        if self.world > 1 and not torch.distributed.is_initialized():
            torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")
        if device.type == "cuda" and self.world > 1:
            self.device = device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
            torch.cuda.set_device(device)
        torch.manual_seed(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.model = CDFCVAE(cfg.model).to(device)
        self.loss = PerceptualLoss(cfg.perceptual).to(device)
        if device.type == "cuda":
            self.model = self.model.to(memory_format=torch.channels_last)
        self.cycle, self.history = 1, {"1": [], "2": []}
        self.stopping = {c: EarlyStopping(cfg.patience, cfg.min_improvement) for c in ("1", "2")}
        self.best: dict[str, torch.Tensor] = {}
        self.optimizer = self._make_optimizer()

    # Parameters each cycle trains.
    def _trainable(self) -> list[nn.Parameter]:
        m = self.model
        if self.cycle == 1:
            return [*m.encoder_real.parameters(), *m.decoder.parameters()]
        encoder = m.encoder_sim if self.cfg.cycle2 == "second_encoder" else m.encoder_real
        return [*encoder.parameters(), *(m.decoder.parameters() if self.cfg.cycle2_train_decoder else [])]

    def _domain(self) -> Literal["real", "sim"]:
        return "real" if self.cycle == 1 or self.cfg.cycle2 == "shared_encoder" else "sim"

    def _make_optimizer(self) -> torch.optim.Adam:
        self.model.requires_grad_(False)
        params = self._trainable()
        for p in params:
            p.requires_grad_(True)
        return torch.optim.Adam(params, lr=self.cfg.learning_rate, betas=self.cfg.adam_betas)

    def _wrapped(self) -> nn.Module:
        if self.world > 1:
            return nn.parallel.DistributedDataParallel(self.model, find_unused_parameters=True)
        return self.model

    def _autocast(self) -> Any:
        if self.device.type == "cuda":
            return torch.autocast("cuda", dtype=torch.bfloat16)
        return nullcontext()

    def _to_device(self, batch: torch.Tensor) -> torch.Tensor:
        batch = batch.to(self.device, non_blocking=True)
        return batch.contiguous(memory_format=torch.channels_last) if self.device.type == "cuda" else batch

    # --- epochs
    def train_epoch(self, data: GridFrames, net: nn.Module, label: str) -> dict[str, float]:
        self.model.train()
        totals = np.zeros(3)
        n_batches = (len(data) + self.cfg.batch_size - 1) // self.cfg.batch_size
        bar = tqdm(batches(data.images, self.cfg.batch_size, self.rng, self.cfg.flip_beams), desc=label,
                   total=n_batches, unit="batch", leave=False, disable=not (self.progress and self.rank == 0))
        for i, batch in enumerate(bar):
            batch = self._to_device(batch[self.rank::self.world] if self.world > 1 else batch)
            with self._autocast():
                x_hat, mu, logvar = net(batch, self._domain())
                total, perceptual, kl = self.loss(x_hat, self.model.reconstruction_target(batch), mu, logvar)
            self.optimizer.zero_grad(set_to_none=True)
            total.backward()
            self.optimizer.step()
            totals += [total.item(), perceptual.item(), kl.item()]
            bar.set_postfix(loss=f"{totals[0] / (i + 1):.4g}", refresh=False)
        mean = totals / max(n_batches, 1)
        return {"train_loss": mean[0], "train_perceptual": mean[1], "train_kl": mean[2]}

    @torch.no_grad()
    def validate(self, data: GridFrames) -> dict[str, float]:
        """Loss of the posterior mean (z = mu, dropout off): deterministic, so early stopping is too."""
        self.model.eval()
        encoder = self.model.encoder(self._domain())
        totals, count = np.zeros(3), 0
        for batch in batches(data.images, self.cfg.batch_size, None):
            batch = self._to_device(batch)
            with self._autocast():
                mu, logvar, skips = encoder(batch)
                total, perceptual, kl = self.loss(self.model.decoder(mu, skips),
                                                  self.model.reconstruction_target(batch), mu, logvar)
            totals += len(batch) * np.array([float(total), float(perceptual), float(kl)])
            count += len(batch)
        mean = totals / count
        return {"val_loss": mean[0], "val_perceptual": mean[1], "val_kl": mean[2]}

    def run_cycle(self, data: Data, max_epochs: int, budget: list[int]) -> bool:
        """Train the current cycle until its limit, early stop, or the epoch budget of this call runs out.
        Returns False when interrupted by the budget."""
        key = str(self.cycle)
        record = self.stopping[key]
        net = self._wrapped()
        while record.epochs_done < max_epochs and not record.stopped:
            if budget[0] == 0:
                return False
            label = f"cycle {key} epoch {record.epochs_done + 1}/{max_epochs}"
            row = {"epoch": record.epochs_done + 1, **self.train_epoch(data.train, net, label),
                   **self.validate(data.val)}
            if record.update(row["val_loss"]):
                self.best = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
            self.history[key].append(row)
            budget[0] -= 1
            if self.rank == 0:
                if self.progress:
                    tqdm.write(f"{label}: train {row['train_loss']:.4g} val {row['val_loss']:.4g} "
                               f"(kl {row['val_kl']:.3g}){' *' if record.best_epoch == record.epochs_done else ''}",
                               file=sys.stderr)
                self.save_state()
        return True

    def finish_cycle1(self, real_dir: str | Path, train_recordings: set[str], sim_follows: bool) -> None:
        """Keep cycle 1's best weights, fit the texture the decoder leaves out, and start cycle 2 from them. A
        learned texture waits for the end of cycle 2 when it follows: it is fitted on the simulated frames'
        decoded means, which need the trained sim encoder."""
        if self.best:
            self.model.load_state_dict(self.best)
        if self.model.texture is not None and not self._texture_waits_for_sim(sim_follows):
            self.fit_texture(real_dir, train_recordings)
        if self.rank == 0:
            save_checkpoint(self.model, self.out / "cycle1.safetensors", self._checkpoint_info(),
                            self.cfg.half_precision_checkpoint)
        self._start_cycle2()

    def start_from_cycle1(self, path: str | Path) -> None:
        """Take every weight (and the fitted texture) of a cycle-1 checkpoint of the same model configuration."""
        model, info = load_checkpoint(path)
        if to_dict(model.cfg) != to_dict(self.cfg.model):
            raise ConfigError(f"--cycle1 {path}: its model configuration differs from this run's (config.model)")
        self.model.load_state_dict({k: v.float() if v.is_floating_point() else v
                                    for k, v in model.state_dict().items()})
        record = info.get("early_stopping", {}).get("1")
        if record:
            self.stopping["1"] = EarlyStopping(**record)
        self._start_cycle2()

    def _start_cycle2(self) -> None:
        self.model.encoder_sim.load_state_dict(self.model.encoder_real.state_dict())
        self.cycle, self.best = 2, {}
        self.optimizer = self._make_optimizer()
        if self.rank == 0:
            self.save_state()

    def _texture_waits_for_sim(self, with_sim: bool) -> bool:
        """Whether the texture is fitted after cycle 2 rather than after cycle 1: a learned one, when there is a
        simulated set to draw it on."""
        return with_sim and isinstance(self.model.texture, LearnedTexture)

    def fit_texture(self, real_dir: str | Path, train_recordings: set[str],
                    sim_frames: list[SonarImage] | None = None) -> None:
        """Fit the texture layer on the training recordings' frames (see `fit_model_texture`), on the weights as
        the checkpoint will hold them: the texture learns the decoded means `translate` will draw on (a half-
        precision checkpoint rounds them; `scripts/refit_texture.py`, which loads the checkpoint, fitted the
        shipped texture on the rounded ones while `train` fitted on the unrounded)."""
        if self.cfg.half_precision_checkpoint:
            round_to_half(self.model)
        fit_model_texture(self.model, texture_frames(real_dir, train_recordings), self.cfg.normalisation,
                          self.device, self.cfg.seed, self.cfg.texture_fit, self.progress, sim_frames)

    # --- persistence
    def _checkpoint_info(self) -> dict[str, Any]:
        limits = {"1": self.cfg.epochs1, "2": self.cfg.epochs2}
        # Reaching the epoch limit is not recorded as a stop, so a finished run can be extended with --resume.
        records = {k: {**vars(v), "stopped_reason": v.stopped_reason or f"reached the epoch limit ({limits[k]})"}
                   for k, v in self.stopping.items() if v.epochs_done}
        return {"normalisation": self.cfg.normalisation, "trained_cycles": self.cycle, "early_stopping": records,
                "perceptual": to_dict(self.cfg.perceptual)}

    def save_state(self) -> None:
        tensors = {f"model.{k}": v for k, v in self.model.state_dict().items()}
        tensors.update({f"best.{k}": v for k, v in self.best.items()})
        param_index = {id(p): i for i, p in enumerate(self._trainable())}
        for param, slot in self.optimizer.state.items():
            for name, value in slot.items():
                tensors[f"optim.{param_index[id(param)]}.{name}"] = torch.as_tensor(value)
        tensors["rng.torch"] = torch.get_rng_state()
        tensors = {k: v.detach().cpu().contiguous() for k, v in tensors.items()}
        info = {"format": STATE_FORMAT, "config": to_dict(self.cfg), "cycle": self.cycle, "history": self.history,
                "early_stopping": {k: vars(v) for k, v in self.stopping.items()},
                "rng_numpy": self.rng.bit_generator.state}
        write_atomically(self.out / "state.safetensors", lambda p: save_file(tensors, str(p)))
        write_atomically(self.out / "state.json", lambda p: p.write_text(json.dumps(info, indent=1, default=_jsonable)))

    def load_state(self) -> None:
        info_path, tensor_path = self.out / "state.json", self.out / "state.safetensors"
        try:
            info = json.loads(info_path.read_text())
            tensors = load_file(str(tensor_path))
        except (OSError, ValueError, SafetensorError) as exc:
            raise FormatError(str(self.out), "state", f"cannot resume: {exc}") from exc
        if info.get("format") != STATE_FORMAT:
            raise FormatError(str(info_path), "format", f"expected {STATE_FORMAT!r}")
        saved_cfg = from_dict(TrainConfig, info["config"], str(info_path))
        if to_dict(replace(saved_cfg, epochs1=0, epochs2=0)) != to_dict(replace(self.cfg, epochs1=0, epochs2=0)):
            raise ConfigError(f"{info_path}: the run was started with a different configuration; resume it with "
                              "the same options (only --epochs1/--epochs2 may change)")
        self.cycle = int(info["cycle"])
        self.optimizer = self._make_optimizer()
        self.model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
        self.best = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
        params = self._trainable()
        for key, value in tensors.items():
            if key.startswith("optim."):
                _, index, name = key.split(".", 2)
                self.optimizer.state[params[int(index)]][name] = value.to(self.device) if name != "step" else value
        torch.set_rng_state(tensors["rng.torch"])
        self.rng.bit_generator.state = info["rng_numpy"]
        self.history = info["history"]
        for key, record in info["early_stopping"].items():
            self.stopping[key] = EarlyStopping(**record)

    def finish_training(self, real_dir: str | Path, train_recordings: set[str], sim_dir: str | Path | None) -> None:
        """Keep the last cycle's best weights and, after cycle 2, fit a learned texture on the simulated frames'
        decoded means (what it will texture; see `finish_cycle1`)."""
        if self.best:
            self.model.load_state_dict(self.best)
        if self.cfg.cycle2 == "shared_encoder":
            # Translation always encodes with encoder_sim; here the one shared encoder is it.
            self.model.encoder_sim.load_state_dict(self.model.encoder_real.state_dict())
        if self._texture_waits_for_sim(sim_dir is not None):
            self.fit_texture(real_dir, train_recordings, texture_frames(sim_dir))

    def write_outputs(self, real: Data, sim: Data | None) -> dict[str, Any]:
        extra = self._checkpoint_info()
        save_checkpoint(self.model, self.out / "model.safetensors", extra, self.cfg.half_precision_checkpoint)
        record = {"cycles": extra["early_stopping"], "real_split": real.split,
                  "sim_split": sim.split if sim else None, "n_real": [len(real.train), len(real.val)],
                  "n_sim": [len(sim.train), len(sim.val)] if sim else None}
        (self.out / "early_stopping.json").write_text(json.dumps(record, indent=2, default=_jsonable) + "\n")
        from sonar_realism.plots import line_plot

        series = {}
        offset = 0
        for key in ("1", "2"):
            rows = self.history[key]
            x = [offset + r["epoch"] for r in rows]
            series[f"cycle {key} train"] = (x, [r["train_loss"] for r in rows])
            series[f"cycle {key} val"] = (x, [r["val_loss"] for r in rows])
            offset += len(rows)
        line_plot({k: v for k, v in series.items() if v[0]}, self.out / "loss_curves.png",
                  title="cDFCVAE loss (perceptual + beta*KL)", xlabel="epoch (cycle 1, then cycle 2)",
                  ylabel="loss", logy=True)
        return record


def texture_frames(real_dir: str | Path, recordings: set[str] | None = None) -> list[SonarImage]:
    """The single-sample frames of `recordings` (None: all) under `real_dir`: what the texture layer is fitted on
    (and, from a simulated set, what a learned texture is drawn on while it is fitted)."""
    frames = [frame for source in recording_sources(Path(real_dir)) for frame in read_frames(source)
              if (recordings is None or recording_of(frame, source.name) in recordings) and frame.intensity.ndim == 2]
    if not frames:
        raise ConfigError(f"{real_dir}: no single-sample frames of {sorted(recordings or ['any recording'])} to fit "
                          "the texture on")
    return frames


def fit_model_texture(model: CDFCVAE, frames: list[SonarImage], normalisation: str, device: torch.device,
                      seed: int = 0, schedule: TextureFitConfig = DEFAULT_FIT, progress: bool = False,
                      sim_frames: list[SonarImage] | None = None) -> None:
    """Fit the model's texture layer on real frames at their own resolution, around one decoded draw of each at
    TEXTURE_FIT_TEMPERATURE (the mean field a translation textures): the texture the decoder cannot express.
    Speckle (models/speckle.py): statistics, grain matched to the frames' (`SpeckleField.match_grain`); learned
    (models/learned_texture.py): the generator trained against a patch critic for `schedule`, drawn on the
    decoded means of `sim_frames` when given (what it will texture in translation), else on the real frames'
    own. Uses TEXTURE_FIT_FRAMES frames evenly spaced over each list."""
    assert model.texture is not None
    model.eval()
    generator = torch.Generator(device=device).manual_seed(seed)

    def decoded_means(picked: list[SonarImage], domain: Literal["real", "sim"]) -> list[np.ndarray]:
        means = []
        with torch.no_grad():
            for frame in picked:
                x = torch.from_numpy(to_model_grid(frame, model.cfg.grid, normalisation))[None, None]
                mean = model.sample(x.to(device), 1, TEXTURE_FIT_TEMPERATURE, generator, domain=domain)[0, 0]
                means.append(np.clip(from_model_grid(frame, mean.float().cpu().numpy()), 0.0, 1.0))
        return means

    picked = _evenly_spaced(frames)
    images = [normalise(frame, "frame_max") for frame in picked]
    means = decoded_means(picked, "real")
    if isinstance(model.texture, LearnedTexture):
        draw_on = None if sim_frames is None else decoded_means(_evenly_spaced(sim_frames), "sim")
        model.texture.fit(images, means, seed, schedule, progress, draw_on)
    else:
        model.texture.fit(images, means, seed=seed)


def texture_fit_indices(count: int) -> np.ndarray:
    """Which of `count` frames the texture is fitted on: TEXTURE_FIT_FRAMES of them, evenly spaced."""
    return np.linspace(0, count - 1, min(TEXTURE_FIT_FRAMES, count)).astype(int)


def _evenly_spaced(frames: list[SonarImage]) -> list[SonarImage]:
    return [frames[i] for i in texture_fit_indices(len(frames))]


def fit(cfg: TrainConfig, real_dir: str | Path, sim_dir: str | Path | None, out: str | Path, *,
        device: str = "auto", resume: bool = False, max_epochs_now: int | None = None,
        progress: bool = True, cycle1: str | Path | None = None) -> dict[str, Any]:
    """Train (or resume) a run in `out`. `max_epochs_now` ends this call after that many epochs (a
    time-sliced or pre-emptible job); `resume=True` continues from the state left behind. `cycle1`: a
    checkpoint whose cycle 1 (the real-data VAE and its texture) is reused, so only cycle 2 runs: the way to
    retarget a trained translator to another simulator, as cycle 1 never sees simulated frames.
    Returns {"finished": bool, ...early-stopping record when finished}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    trainer = Trainer(cfg, out, pick_device(device), progress)
    if resume and cycle1 is not None:
        raise ConfigError("--cycle1 starts a run; --resume continues one: give one of them")
    if cfg.epochs1 == 0 and cycle1 is None and not resume:
        print("warning: epochs1 is 0 and no --cycle1 is given: the VAE is not trained on real frames, so cycle 2 "
              "starts from random weights", file=sys.stderr)
    if not resume and (out / "state.json").is_file():
        raise ConfigError(f"--out {out} already holds a training run (state.json): continue it with --resume, or "
                          f"choose another --out")
    if resume:
        if not (out / "state.json").is_file():
            raise ConfigError(f"--resume: {out} holds no training state (state.json)")
        trainer.load_state()
    if cycle1 is not None:
        if sim_dir is None:
            raise ConfigError("--cycle1: reusing cycle 1 only makes sense with --sim for cycle 2")
        trainer.start_from_cycle1(cycle1)
    (out / "config.json").write_text(json.dumps(to_dict(cfg), indent=2) + "\n")
    real = load_data(real_dir, cfg, by_recording=True)
    sim = load_data(sim_dir, cfg, by_recording=False) if sim_dir else None
    budget = [max_epochs_now if max_epochs_now is not None else -1]
    if trainer.cycle == 1:
        if not trainer.run_cycle(real, cfg.epochs1, budget):
            return {"finished": False}
        trainer.finish_cycle1(real_dir, set(real.train.recordings), sim_follows=sim is not None)
    if sim is not None and not trainer.run_cycle(sim, cfg.epochs2, budget):
        return {"finished": False}
    if trainer.rank != 0:
        return {"finished": True}
    trainer.finish_training(real_dir, set(real.train.recordings), sim_dir)
    return {"finished": True, **trainer.write_outputs(real, sim)}


# --- helpers -------------------------------------------------------------------------------------------------------

def write_atomically(path: Path, write: Any) -> None:
    """`write(partial)` then rename over `path`: a run killed while writing leaves the previous file whole."""
    partial = path.with_name(path.name + ".tmp")
    write(partial)
    os.replace(partial, path)


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.integer | np.floating):
        return value.item()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


# --- CLI -----------------------------------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", choices=("cdfcvae", "cyclegan"), default="cdfcvae")
    parser.add_argument("--real", required=True, help="real recordings (any format read_frames reads)")
    parser.add_argument("--sim", help="simulated frames (cdfcvae: for cycle 2; without it only cycle 1 runs)")
    parser.add_argument("--out", required=True, help="run folder (checkpoint, state, curves)")
    parser.add_argument("--epochs1", type=int, help="cdfcvae: cycle-1 epoch limit (default 80)")
    parser.add_argument("--epochs2", type=int, help="cdfcvae: cycle-2 epoch limit (default 60)")
    parser.add_argument("--epochs", type=int, help="cyclegan: epochs (default 200)")
    parser.add_argument("--crop", type=int, help="cyclegan: train on CROP x CROP crops of the frames at their own "
                                                 "resolution (its authors' recipe) instead of on --grid")
    parser.add_argument("--save-every", type=int, default=1, help="cyclegan: write the checkpoint every N epochs "
                                                                   "and after the last (default 1)")
    parser.add_argument("--batch-size", type=int, help="default: 16 (cdfcvae), 1 (cyclegan)")
    parser.add_argument("--grid", help="model grid RANGESxBEAMS (default 128x128)")
    parser.add_argument("--max-frames", type=int, help="use at most this many frames of each set")
    parser.add_argument("--recordings", help="cdfcvae: train only on the real frames of these recordings "
                                             "(comma-separated names, e.g. Oculus_20250805_173650); the rest "
                                             "stays held out for evaluation")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--seed", type=non_negative_int, help="default 0")
    parser.add_argument("--resume", action="store_true", help="continue the run left in --out")
    parser.add_argument("--cycle1", help="cdfcvae: reuse this checkpoint's cycle 1 (the real-data VAE, e.g. "
                                         "RUN/cycle1.safetensors) and run only cycle 2 on --sim")
    parser.add_argument("--config", help="JSON file of TrainConfig keys (model, perceptual, ...); unknown keys "
                                         "are rejected; flags given on the command line win")


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    data: dict[str, Any] = json_object(args.config, "--config", "TrainConfig keys") if args.config else {}
    flags = {"epochs1": args.epochs1, "epochs2": args.epochs2, "batch_size": args.batch_size,
             "max_frames": args.max_frames, "seed": args.seed}
    data.update({k: v for k, v in flags.items() if v is not None})
    if args.recordings:
        data["real_recordings"] = [name.strip() for name in args.recordings.split(",") if name.strip()]
    if args.grid:
        data["model"] = {**data.get("model", {}), "grid": list(parse_grid(args.grid))}
    return from_dict(TrainConfig, data, str(args.config or "config"))


def run(args: argparse.Namespace) -> int:
    if args.model == "cyclegan":
        from sonar_realism.models.train_cyclegan import train

        args.batch_size = args.batch_size or 1
        args.seed = args.seed if args.seed is not None else 0
        args.epochs = args.epochs if args.epochs is not None else 200
        return train(args)
    cyclegan_only = [flag for flag, given in (("--crop", args.crop), ("--epochs", args.epochs is not None)) if given]
    if cyclegan_only:
        raise ConfigError(f"{' and '.join(cyclegan_only)}: for --model cyclegan only (the cDFCVAE trains on --grid "
                          f"for --epochs1 and --epochs2)")
    if args.sim is not None and not args.sim.strip():
        raise ConfigError("--sim: empty; name the simulated frames, or leave --sim out to run cycle 1 only")
    cfg = config_from_args(args)
    started = time.monotonic()
    result = fit(cfg, args.real, args.sim, args.out, device=args.device, resume=args.resume, cycle1=args.cycle1)
    if int(os.environ.get("RANK", 0)) == 0:  # under torchrun every rank gets here; one line is enough
        print(f"trained in {time.monotonic() - started:.0f} s; checkpoint {Path(args.out) / 'model.safetensors'}",
              file=sys.stderr)
    return 0 if result["finished"] else 1
