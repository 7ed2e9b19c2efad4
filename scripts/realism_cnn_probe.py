"""What Table I's realism CNN keys on: it is trained as the evaluation trains it (the first half of the held-out
recording against simulated frames), then scores real frames of the other recording and translated frames with
their grid-scale texture scaled. Markdown table + JSON.

    python scripts/realism_cnn_probe.py --sim-train runs/sim_calibrated_train --sim runs/sim_calibrated_eval \
        --model cdfcvae=sonar_realism/assets/cdfcvae_default.safetensors \
        --model cyclegan=runs/cyclegan_crop/cyclegan.safetensors --out runs/realism_cnn_probe

Each scored set is also shown with its grid-scale texture (the frame less a Gaussian blur of 2 grid cells)
multiplied by `--texture-gains`, and the texture's contrast over lit cells (blurred level > 0.15) is printed
beside the score. Figures of 2026-11-28 in docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from translator_goals import GRID, folder_frames, real_frames  # noqa: E402

from sonar_realism.data import OCULUS_FIT_RECORDING, OCULUS_HELD_OUT_RECORDING  # noqa: E402
from sonar_realism.models.datasets import frames_on_grid  # noqa: E402
from sonar_realism.models.realism_cnn import RealismCNNConfig, realism_scores, train_classifier  # noqa: E402
from sonar_realism.models.translate import load_translator  # noqa: E402

TEXTURE_BLUR = 2.0  # grid cells: what is finer than this is the grid-scale texture
LIT = 0.15  # blurred level above which a cell counts as lit seabed


def _blurred(images: np.ndarray) -> np.ndarray:
    return np.stack([cv2.GaussianBlur(i, (0, 0), TEXTURE_BLUR) for i in images])


def with_texture_gain(images: np.ndarray, gain: float) -> np.ndarray:
    """The grid-scale texture multiplied by `gain` around the blurred level, clipped at 0, max-scaled again."""
    level = _blurred(images)
    scaled = np.clip(level + gain * (images - level), 0.0, None)
    return (scaled / scaled.reshape(len(scaled), -1).max(axis=1)[:, None, None]).astype(np.float32)


def texture_contrast(images: np.ndarray) -> float:
    level = _blurred(images)
    return float(((images - level) / (level + 0.03))[level > LIT].std())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim-train", required=True, help="simulated frames the CNN learns 'simulated' from")
    parser.add_argument("--sim", required=True, help="simulated frames to translate and score")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=CKPT")
    parser.add_argument("--n-sim", type=int, default=60)
    parser.add_argument("--texture-gains", type=float, nargs="+", default=[1.1, 1.3])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)

    held = frames_on_grid(real_frames(OCULUS_HELD_OUT_RECORDING), GRID)
    cnn_real, reference = held[:len(held) // 2], held[len(held) // 2:]
    sim_train = frames_on_grid(folder_frames(args.sim_train, args.n_sim), GRID)
    inputs = folder_frames(args.sim, args.n_sim)
    scored = {"real (held out, second half)": reference, "real (other recording)":
              frames_on_grid(real_frames(OCULUS_FIT_RECORDING, 3), GRID), "raw sim": frames_on_grid(inputs, GRID)}
    for spec in args.model:
        name, _, path = spec.partition("=")
        translated = load_translator(path, "cpu").translate(inputs, n=1, seed=0)
        scored[name] = frames_on_grid([f.sample(0) for f in translated], GRID)
    variants = {name: images for name, images in scored.items()}
    for name in ("raw sim", *[spec.partition("=")[0] for spec in args.model]):
        for gain in args.texture_gains:
            variants[f"{name}, texture x{gain:g}"] = with_texture_gain(scored[name], gain)

    scores: dict[str, list[float]] = {name: [] for name in variants}
    for seed in args.seeds:
        cnn = train_classifier(cnn_real, sim_train, dataclasses.replace(RealismCNNConfig(), seed=seed))
        for name, images in variants.items():
            scores[name].append(float(realism_scores(cnn, images).mean()))
    rows = {name: {"score": float(np.mean(s)), "runs": s, "texture_contrast": texture_contrast(variants[name])}
            for name, s in scores.items()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "probe.json").write_text(json.dumps({"rows": rows, "seeds": args.seeds, "command": " ".join(sys.argv)},
                                               indent=1) + "\n")
    print("| scored set | realism CNN score, mean (per seed) | grid-scale texture contrast, lit cells |")
    print("|---|---:|---:|")
    for name, row in rows.items():
        runs = " / ".join(f"{r:.3f}" for r in row["runs"])
        print(f"| {name} | {row['score']:.3f} ({runs}) | {row['texture_contrast']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
