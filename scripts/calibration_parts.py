"""Which part of one calibration makes its frames read differently from another's: the training-side texture test.

    python scripts/calibration_parts.py --base CALIB.json --donor OTHER.json \\
        --parts effects.elevation_spread,effects.range_blur,effects.beam_sidelobes --parts seabed --seeds 0 1 2 3

For each `--parts` group (dotted paths into the CALIB.json: `seabed`, `effects.tvg_noise`, `texture.export_knee`,
…) the base calibration is simulated with those values taken from the donor (the empty group: the base as it is)
and its frames are compared with every third frame of the fit recording by the texture two-sample test (32 × 32
patches, level removed), one new set of sim frames and classifier per seed. Nothing of the held-out recording is
read; a learned texture is not refitted, so a group reads the donor's values under the base's generator. Lower is
better (0.5: not told apart). The per-seed spread is wide (0.7–1.0): compare groups seed by seed.
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.config import from_dict, to_dict  # noqa: E402
from sonar_realism.data import OCULUS_FIT_RECORDING, real_oculus_dir  # noqa: E402
from sonar_realism.evaluate.two_sample import TextureTestConfig, texture_two_sample_test  # noqa: E402
from sonar_realism.io import load_recording  # noqa: E402
from sonar_realism.sim.calibrated import simulate_calibrated  # noqa: E402
from sonar_realism.sim.calibration import Calibration, load_calibration  # noqa: E402
from sonar_realism.sim.fingerprint import per_frame_rescaled  # noqa: E402


def with_parts(base: dict, donor: dict, paths: list[str]) -> dict:
    """A copy of `base` with the values at the dotted `paths` taken from `donor`."""
    merged = copy.deepcopy(base)
    for path in paths:
        *parents, key = path.split(".")
        source, target = donor, merged
        for name in parents:
            source, target = source[name], target[name]
        target[key] = source[key]
    return merged


def load_merged(merged: dict) -> Calibration:
    """The merged calibration, validated as a loaded CALIB.json is (`from_dict` rejects unknown keys and runs
    `Calibration.validate`)."""
    return from_dict(Calibration, merged, where="calibration (base with the donor's parts)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the CALIB.json (or shipped name) to change")
    parser.add_argument("--donor", required=True, help="the CALIB.json (or shipped name) the parts come from")
    parser.add_argument("--parts", action="append", default=[], metavar="PATH[,PATH...]",
                        help="one group of dotted paths; repeat for more groups (the base alone is always read)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = parser.parse_args()
    torch.set_num_threads(1)
    base, donor = (to_dict(load_calibration(name)) for name in (args.base, args.donor))
    fit = load_recording(real_oculus_dir(), OCULUS_FIT_RECORDING)
    reference = [per_frame_rescaled(frame.intensity) for frame in fit[0::3]]
    print("| parts from the donor | texture accuracy, mean | per seed |")
    print("|---|---:|---|")
    for group in ["", *args.parts]:
        calibration = load_merged(with_parts(base, donor, [p for p in group.split(",") if p]))
        accuracies = []
        for seed in args.seeds:
            frames = simulate_calibrated(calibration, len(reference), seed=1000 + seed)
            sim = [per_frame_rescaled(frame.intensity) for frame, _ in frames]
            accuracies.append(texture_two_sample_test(reference, sim, TextureTestConfig(seed=seed)).accuracy)
        print(f"| {group or '(none: the base)'} | {np.mean(accuracies):.3f} | "
              + " / ".join(f"{a:.2f}" for a in accuracies) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
