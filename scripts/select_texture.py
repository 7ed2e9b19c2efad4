"""Choose between translator checkpoints on the training side only: the texture two-sample test of each one's
translations of training-sim frames against the fit recording's frames the texture was not fitted on.

    python scripts/select_texture.py --sim runs/sim_calibrated_train \
        --model a=runs/texfit/paired0/ema/model.safetensors --model b=runs/texfit/paired1/ema/model.safetensors

The learned texture is fitted on the frames `models.train.texture_fit_indices` picks, evenly spaced over the
recording; the frames between them are the reference here. They are neighbours of fitted pings, so the
test reads lower than on another recording: it ranks candidates, it does not measure the goal. Nothing of the
held-out recording is read. Lower accuracy is better (0.5: not told apart).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from translator_goals import folder_frames, real_frames  # noqa: E402

from sonar_realism.data import OCULUS_FIT_RECORDING  # noqa: E402
from sonar_realism.evaluate.two_sample import TextureTestConfig, texture_two_sample_test  # noqa: E402
from sonar_realism.models.datasets import normalise  # noqa: E402
from sonar_realism.models.train import texture_fit_indices  # noqa: E402
from sonar_realism.models.translate import load_translator  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim", required=True, help="simulated frames the translators were trained on")
    parser.add_argument("--model", action="append", required=True, metavar="NAME=CKPT")
    parser.add_argument("--n-sim", type=int, default=90)
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(8)))
    args = parser.parse_args()
    torch.set_num_threads(1)

    fit = real_frames(OCULUS_FIT_RECORDING)
    fitted = set(texture_fit_indices(len(fit)).tolist())
    reference = [normalise(frame, "frame_max") for i, frame in enumerate(fit) if i not in fitted]
    inputs = folder_frames(args.sim, args.n_sim)
    print(f"{len(reference)} reference frames of {OCULUS_FIT_RECORDING} (not fitted on), {len(inputs)} sim inputs")
    print("| model | texture 2-sample accuracy, mean (AUC) | per seed |")
    print("|---|---:|---|")
    for spec in args.model:
        name, _, path = spec.partition("=")
        outputs = [normalise(f.sample(0), "frame_max")
                   for f in load_translator(path, "cpu").translate(inputs, n=1, seed=0)]
        runs = [texture_two_sample_test(reference, outputs, TextureTestConfig(seed=s)) for s in args.seeds]
        print(f"| {name} | {np.mean([r.accuracy for r in runs]):.3f} ({np.mean([r.auc for r in runs]):.3f}) | "
              + " / ".join(f"{r.accuracy:.2f}" for r in runs) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
