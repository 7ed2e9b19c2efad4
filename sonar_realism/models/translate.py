"""Simulated frames -> n realistic samples each, with a trained cDFCVAE; and `sonar-realism translate`.

Each frame is resampled to the model grid, normalised as in training, encoded once by the simulation
encoder; n latents z = mu + temperature·sigma·eps are decoded as one batch, and the samples are resampled
back onto the input's own ranges and bearings. The result is one SonarImage per input with float32
intensity [n, n_ranges, n_beams] in [0, 1] and the translation's provenance in `meta["provenance"]`.

Noise is drawn from one generator seeded with `seed`, frame after frame, so a seeded call is reproducible
and a frame's samples do not depend on the frames translated after it.
"""

from __future__ import annotations

import argparse
import secrets
import sys
from collections.abc import Iterator, Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any, get_args

import numpy as np
import torch

from sonar_realism.arguments import non_negative_int, not_the_input, output_file, output_folder, positive_int
from sonar_realism.errors import ConfigError, FormatError, FrameError
from sonar_realism.frames import SonarImage
from sonar_realism.models.cdfcvae import CDFCVAE, file_sha256, load_checkpoint
from sonar_realism.models.cyclegan import CycleGANTranslator, is_cyclegan_checkpoint
from sonar_realism.models.datasets import Normalisation, from_model_grid, to_model_grid
from sonar_realism.models.device import pick_device
from sonar_realism.models.speckle import as_sensor_bytes
from sonar_realism.models.speckle_fit import EXPORT_LEVELS

DEFAULT_CHECKPOINT = Path(__file__).resolve().parents[1] / "assets" / "cdfcvae_default.safetensors"
# Frames encoded per forward pass: bounds memory at n samples each (decodes = chunk × n).
_FRAMES_PER_PASS = 16


class Translator:
    """A loaded cDFCVAE that turns simulated frames into realistic samples."""

    def __init__(self, model: CDFCVAE, info: dict[str, Any], checkpoint: Path, device: torch.device) -> None:
        self.model = model.to(device).eval()
        self.info = info
        self.device = device
        self.checkpoint = checkpoint
        # Hashed here, once: the translator node stamps every output with it instead of reading the file again.
        self.checkpoint_sha256 = file_sha256(checkpoint)
        self.normalisation = info.get("normalisation", "frame_max")
        if self.normalisation not in get_args(Normalisation):
            raise FormatError(f"{checkpoint.with_suffix('.json')}", "normalisation",
                              f"{self.normalisation!r} is none of {', '.join(get_args(Normalisation))}")
        # channels_last on a CPU too: oneDNN's convolutions run 1.3-5x faster in it than in NCHW here.
        self.model = self.model.to(memory_format=torch.channels_last)

    @classmethod
    def from_checkpoint(cls, path: str | Path = DEFAULT_CHECKPOINT, device: str = "auto") -> Translator:
        chosen = pick_device(device)
        model, info = load_checkpoint(path)
        return cls(model, info, Path(path), chosen)

    @property
    def grid(self) -> tuple[int, int]:
        return tuple(self.model.cfg.grid)  # type: ignore[return-value]

    def translate(self, frames: Sequence[SonarImage], n: int, temperature: float = 1.0,
                  seed: int | None = None) -> list[SonarImage]:
        """n samples of each frame, each output on its input's geometry, [n, R, B]: with a texture layer and
        temperature > 0 the sensor's 8-bit export (uint8, intensity_scale 255), else float32 in [0, 1]."""
        if n < 1:
            raise ConfigError(f"n: need at least one sample, got {n}")
        if not np.isfinite(temperature) or temperature < 0:
            raise ConfigError(f"temperature: expected a finite number >= 0, got {temperature}")
        seed = secrets.randbits(63) if seed is None else int(seed)
        generator = torch.Generator(device=self.device).manual_seed(seed)
        provenance = {"model": "cdfcvae", "checkpoint": self.checkpoint.name,
                      "checkpoint_sha256": self.checkpoint_sha256[:16], "temperature": float(temperature),
                      "seed": seed, "n_samples": n}
        # Speckle is sampled on the CPU at each frame's own resolution from a generator of its own, so a seeded
        # call gives the same texture on any device. Temperature 0 asks for the posterior mean: no speckle.
        texture_generator = None
        if self.model.texture is not None and temperature > 0:
            texture_generator = torch.Generator().manual_seed(seed ^ 0x5EC1E)
        out: list[SonarImage] = []
        for start in range(0, len(frames), _FRAMES_PER_PASS):
            out.extend(self._translate_chunk(frames[start:start + _FRAMES_PER_PASS], n, temperature, generator,
                                             texture_generator, provenance))
        return out

    def _translate_chunk(self, frames: Sequence[SonarImage], n: int, temperature: float,
                         generator: torch.Generator, texture_generator: torch.Generator | None,
                         provenance: dict[str, Any]) -> list[SonarImage]:
        for frame in frames:
            if frame.intensity.ndim != 2:
                raise FrameError(f"translate: frame seq {frame.seq} already has {frame.n_samples} samples; "
                                 "pass single [ranges, beams] frames")
        batch = np.stack([to_model_grid(frame, self.grid, self.normalisation) for frame in frames])
        x = torch.from_numpy(batch).unsqueeze(1).to(self.device).contiguous(memory_format=torch.channels_last)
        with torch.inference_mode(), (torch.autocast("cuda", dtype=torch.bfloat16) if self.device.type == "cuda"
                                      else nullcontext()):
            samples = self.model.sample(x, n, temperature, generator)
        samples_np = samples.float().clamp(0.0, 1.0).cpu().numpy()
        return [self._back_to_input_geometry(frame, samples_np[i], provenance, texture_generator)
                for i, frame in enumerate(frames)]

    def _back_to_input_geometry(self, frame: SonarImage, samples: np.ndarray, provenance: dict[str, Any],
                                texture_generator: torch.Generator | None) -> SonarImage:
        meta = dict(frame.meta)
        meta["provenance"] = {**meta.get("provenance", {}), "translator": provenance} \
            if isinstance(meta.get("provenance"), dict) else {"translator": provenance}
        intensity = np.clip(from_model_grid(frame, samples), 0.0, 1.0)
        if texture_generator is None:
            return frame.replace(intensity=intensity, intensity_scale=1.0, meta=meta)
        # The texture's export is the sensor's 8-bit output (EXPORT_LEVELS steps of the frame's maximum), so it
        # travels as uint8, exactly and in a quarter of float32's bytes, as the calibrated simulator's frames do.
        exported = self.model.texture.sample(intensity, texture_generator)
        return frame.replace(intensity=as_sensor_bytes(exported), intensity_scale=float(EXPORT_LEVELS), meta=meta)


def load_translator(path: str | Path, device: str = "auto") -> Translator | CycleGANTranslator:
    """The translator a checkpoint asks for: the cDFCVAE, or the CycleGAN baseline (same `.translate`). The one
    loader that tells the two apart; `translate`, `evaluate` and the scripts all load through it."""
    if is_cyclegan_checkpoint(path):
        return CycleGANTranslator.from_checkpoint(path, device)
    return Translator.from_checkpoint(path, device)


# --- CLI -----------------------------------------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", default=str(DEFAULT_CHECKPOINT),
                        help="cDFCVAE (or CycleGAN baseline) checkpoint, .safetensors with its .json; "
                             "default: the shipped cDFCVAE")
    parser.add_argument("--in", dest="inp", required=True, help="simulated frames (any format read_frames reads)")
    parser.add_argument("--out", required=True, help="output: a frames folder (+ contact_sheet.png), or NAME.npz / "
                                                     "NAME.mcap (ROS 2 bag; + NAME.contact_sheet.png beside it)")
    parser.add_argument("--topic", help="--in a ROS bag: its sonar topic (default: the one found by message type)")
    parser.add_argument("--n", type=int, default=8, help="samples per frame (default 8)")
    parser.add_argument("--temperature", type=float, default=1.0, help="latent noise scale s (default 1)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="noise seed (default 0)")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--max-frames", type=positive_int, help="translate at most this many frames")


def _chunks(frames: Iterator[SonarImage], size: int, limit: int | None) -> Iterator[list[SonarImage]]:
    chunk: list[SonarImage] = []
    for count, frame in enumerate(frames):
        if limit is not None and count >= limit:
            break
        chunk.append(frame)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from sonar_realism.io import FILE_SUFFIXES, ReadReport, read_frames, write_frames
    from sonar_realism.plots import image_grid

    not_the_input(args.out, args.inp, "--out", "--in")
    if Path(args.out).suffix.lower() in FILE_SUFFIXES:
        output_file(args.out, "--out")
    else:
        output_folder(args.out, "--out")
    translator = load_translator(args.checkpoint, args.device)
    sheet: list[np.ndarray] = []
    columns = 1 + min(args.n, 7)

    report = ReadReport()

    def translated() -> Iterator[SonarImage]:
        inputs = tqdm(read_frames(args.inp, report, topic=args.topic), desc="translate", unit="frame")
        for index, chunk in enumerate(_chunks(inputs, _FRAMES_PER_PASS, args.max_frames)):
            # Chunk k draws its noise from (seed, k): reproducible end to end and independent across chunks.
            chunk_seed = int(np.random.SeedSequence([args.seed, index]).generate_state(1, np.uint64)[0] >> 1)
            outputs = translator.translate(chunk, args.n, args.temperature, seed=chunk_seed)
            for frame, output in zip(chunk, outputs, strict=True):
                if len(sheet) < 4 * columns:
                    sheet.append(frame.normalized())
                    sheet.extend(output.intensity[: columns - 1])
                yield output

    count = write_frames(translated(), args.out)
    if report.problems:  # the frames read are translated; what could not be read is said, not passed over
        print(f"warning: --in {args.inp}: {report.skipped['corrupt record']} record(s) could not be read, e.g. "
              f"{report.problems[0]}", file=sys.stderr)
    if not count:
        raise ConfigError(f"--in {args.inp}: no frames to translate")
    labels = [("input" if i % columns == 0 else f"sample {i % columns}") for i in range(len(sheet))]
    out = Path(args.out)
    sheet_path = out.with_name(out.stem + ".contact_sheet.png") if out.is_file() else out / "contact_sheet.png"
    image_grid(sheet, sheet_path, ncols=columns, labels=labels)
    print(f"{count} frames x {args.n} samples -> {args.out}", file=sys.stderr)
    return 0
