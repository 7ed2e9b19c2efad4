"""Can the translator pass the two-sample tests on *real* frames? The check to run before any sim or translator run.

    OMP_NUM_THREADS=1 python scripts/reconstruction_realism.py --model sonar_realism/assets/cdfcvae_default.safetensors

The fit recording (OCULUS_FIT_RECORDING, the one the translator trained on) is split into interleaved halves
A and B. Each test is A against B made by:
- "real (null)": B itself, the floor of both tests on this split;
- "reconstruction": the translator's real-domain encoder and decoder on B (temperature 1) with its speckle:
  what a perfect sim-to-real encoder would give at best;
- "speckle around own level": the speckle layer sampled around B's own local mean (sim/texture.local_mean):
  the texture model with the scene taken from the frame itself.
If "reconstruction" is told apart, no simulator and no sim encoder can bring the held-out tests down; on
2026-11-23 the texture test gave 1.00 and the whole-frame test 0.85-0.90 (docs/RESULTS.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from sonar_realism.data import OCULUS_FIT_RECORDING, oculus_recording_files
from sonar_realism.evaluate.two_sample import (
    TextureTestConfig,
    TwoSampleResult,
    classifier_two_sample_test,
    texture_two_sample_test,
)
from sonar_realism.frames import SonarImage
from sonar_realism.io import read_frames
from sonar_realism.models.datasets import frames_on_grid, from_model_grid, normalise, to_model_grid
from sonar_realism.models.translate import load_translator
from sonar_realism.sim.texture import local_mean

GRID = (128, 128)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", required=True, help="cDFCVAE checkpoint with a speckle layer")
    parser.add_argument("--frames", type=int, default=120, help="frames of the fit recording, evenly spaced")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--json", help="write the figures here too")
    args = parser.parse_args()
    torch.set_num_threads(1)
    files = oculus_recording_files(OCULUS_FIT_RECORDING)
    if not files:
        raise SystemExit(f"no frames of {OCULUS_FIT_RECORDING}: set SONAR_REALISM_DATA to the data folder")
    frames = [frame for path in files for frame in read_frames(path)]
    frames = [frames[i] for i in np.linspace(0, len(frames) - 1, min(args.frames, len(frames))).astype(int)]
    half_a, half_b = frames[0::2], frames[1::2]
    model = load_translator(args.model, "cpu").model
    if model.texture is None:
        raise SystemExit(f"{args.model}: no speckle layer to test")
    generator = torch.Generator().manual_seed(0)

    def reconstruction(frame: SonarImage) -> np.ndarray:
        x = torch.from_numpy(to_model_grid(frame, model.cfg.grid, "frame_max"))[None, None]
        mean = model.sample(x, 1, 1.0, generator, domain="real")[0, 0].numpy()
        return model.texture.sample(np.clip(from_model_grid(frame, mean), 0.0, 1.0)[None], generator)[0]

    def speckle_around_own_level(frame: SonarImage) -> np.ndarray:
        level = np.clip(local_mean(normalise(frame, "frame_max")), 0.0, 1.0)
        return model.texture.sample(level[None], generator)[0]

    candidates = {"real (null)": [normalise(f, "frame_max") for f in half_b],
                  "reconstruction": [reconstruction(f) for f in half_b],
                  "speckle around own level": [speckle_around_own_level(f) for f in half_b]}
    native_a = [normalise(f, "frame_max") for f in half_a]
    grid_a = frames_on_grid(half_a, GRID)
    rows: dict[str, dict[str, list[float]]] = {}
    for name, native in candidates.items():
        grid = frames_on_grid([f.replace(intensity=image, intensity_scale=1.0)
                               for f, image in zip(half_b, native, strict=True)], GRID)
        texture = [texture_two_sample_test(native_a, native, TextureTestConfig(seed=s)) for s in args.seeds]
        whole = [classifier_two_sample_test(grid_a, grid, seed=s) for s in args.seeds]
        rows[name] = {"texture_accuracy": _field(texture, "accuracy"), "texture_auc": _field(texture, "auc"),
                      "whole_frame_accuracy": _field(whole, "accuracy"), "whole_frame_auc": _field(whole, "auc")}
        print(f"{name} done", file=sys.stderr)
    print("| B made by | texture: accuracy (AUC) per seed | whole frame: accuracy (AUC) per seed |\n|---|---|---|")
    for name, row in rows.items():
        print(f"| {name} | {_cell(row, 'texture')} | {_cell(row, 'whole_frame')} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"model": args.model, "frames": len(frames), "seeds": args.seeds,
                                               "tests": rows}, indent=1) + "\n")
    return 0


def _field(results: list[TwoSampleResult], name: str) -> list[float]:
    return [getattr(result, name) for result in results]


def _cell(row: dict[str, list[float]], test: str) -> str:
    return " / ".join(f"{acc:.2f} ({auc:.2f})" for acc, auc in zip(row[f"{test}_accuracy"], row[f"{test}_auc"],
                                                                   strict=True))


if __name__ == "__main__":
    raise SystemExit(main())
