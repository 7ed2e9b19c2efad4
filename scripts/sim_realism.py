"""How much the calibrated simulator looks like the sensor: issue 11's goals, measured in one run.

    python scripts/sim_realism.py [--calibration CALIB.json] [--seeds 0 1 2] [--json OUT.json]
    python scripts/sim_realism.py --aris [--calibration CALIB.json]

Oculus (default): calibrate on recording OCULUS_FIT_RECORDING (or take --calibration made from it), render as
many frames as the held-out recording OCULUS_HELD_OUT_RECORDING has, and compare both the calibrated sim and
the fit recording itself (the real-vs-real yardstick) with the held-out recording. Nothing is tuned on the
held-out recording. ARIS: calibrate on every other frame of the water-tank set and compare with the others.
`--against fit` reads the training side only, to choose between calibrations without the held-out recording:
every third frame of the fit recording in its place, and the frames after those as the "yardstick" (neighbouring
pings of the same recording: a floor, not a yardstick).

Measures (all on frames scaled by their own maximum, the real export's rule):
- whole-frame two-sample classifier on 128 x 128 model grids (evaluate.two_sample), balanced accuracy;
- texture patch two-sample test at native resolution (32 x 32 patches, patch mean removed);
- near-zero pixel fraction (<= 2 counts of 255);
- mean range and bearing profiles (48 bins): mean |sim - real| over the real profile's mean;
- speckle contrast (evaluate.texture.speckle_statistics per frame, mean over range bands);
- grain: lag-1 correlation of the detrended frame along range and across beams (evaluate.statistics);
- the texture's range asymmetry (evaluate.texture.range_asymmetry), beside the held-out recording's;
- the targets (sim/annotations.py's measures): share of frames with one, count in such a frame, median width across
  the fan, range share and return over the seabed median, and the objects' share of the frame's cells, for the sim
  (its masks: the lit surface) and the held-out frames (their own annotations: the ARIS set's masks, classes 1-10;
  the Oculus set's YOLO boxes, which frame the whole echo, so their area is larger by convention).
Classifier tests are averaged over --seeds (each seed: new sim frames and a new classifier initialisation).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

from sonar_realism.data import OCULUS_FIT_RECORDING, OCULUS_HELD_OUT_RECORDING, real_aris_dir, real_oculus_dir  # noqa: E402
from sonar_realism.evaluate.statistics import _detrend, lag_correlation  # noqa: E402
from sonar_realism.evaluate.texture import range_asymmetry, speckle_statistics  # noqa: E402
from sonar_realism.evaluate.two_sample import (  # noqa: E402
    TextureTestConfig,
    classifier_two_sample_test,
    texture_two_sample_test,
)
from sonar_realism.frames import SonarImage  # noqa: E402
from sonar_realism.io import load_recording  # noqa: E402
from sonar_realism.models.datasets import frames_on_grid  # noqa: E402
from sonar_realism.sim.annotations import (  # noqa: E402
    AnnotatedObject,
    mask_objects,
    measure_objects,
    parse_classes,
    read_annotations,
)
from sonar_realism.sim.calibrate import CalibrateConfig, calibrate, prepare_frames  # noqa: E402
from sonar_realism.sim.calibrated import simulate_calibrated  # noqa: E402
from sonar_realism.sim.calibration import Calibration, load_calibration, save_calibration  # noqa: E402
from sonar_realism.sim.fingerprint import PROFILE_BINS, per_frame_rescaled, resample_profile  # noqa: E402
from sonar_realism.sim.measure import near_zero_fraction  # noqa: E402

GRID = (128, 128)


def scaled(frames: list[SonarImage]) -> list[np.ndarray]:
    return [per_frame_rescaled(f.intensity) for f in frames]


def statistics(images: list[np.ndarray]) -> dict[str, object]:
    rows = np.mean([resample_profile(i.mean(axis=1), PROFILE_BINS) for i in images], axis=0)
    cols = np.mean([resample_profile(i.mean(axis=0), PROFILE_BINS) for i in images], axis=0)
    contrast = np.nanmean([np.nanmean([b.contrast for b in speckle_statistics(i[None])]) for i in images])
    along = np.mean([lag_correlation(_detrend(i[None], 9), 1, 1)[0, 0] for i in images])
    across = np.mean([lag_correlation(_detrend(i[None], 9), 2, 1)[0, 0] for i in images])
    return {"near_zero": float(np.mean([near_zero_fraction(i) for i in images])), "range_profile": rows,
            "bearing_profile": cols, "speckle_contrast": float(contrast), "grain_range": float(along),
            "grain_beams": float(across), "range_asymmetry": range_asymmetry(images)}


def compare(candidate: dict[str, object], real: dict[str, object]) -> dict[str, float]:
    out = {"near_zero_points": 100 * (float(candidate["near_zero"]) - float(real["near_zero"]))}
    for key in ("range_profile", "bearing_profile"):
        a, b = np.asarray(candidate[key]), np.asarray(real[key])
        out[f"{key}_rel"] = float(np.abs(a - b).mean() / max(float(b.mean()), 1e-9))
    for key in ("speckle_contrast", "grain_range", "grain_beams"):
        out[f"{key}_rel"] = float(candidate[key]) / float(real[key]) - 1
    # a signed skewness near 0 for symmetric texture: the two values side by side, not a ratio
    out["range_asymmetry"], out["range_asymmetry_real"] = float(candidate["range_asymmetry"]), float(
        real["range_asymmetry"])
    return out


def object_statistics(frames: list[SonarImage], objects: Sequence[Sequence[AnnotatedObject]]) -> dict[str, float]:
    measured = [measure_objects(f, i, o) for f, i, o in zip(frames, scaled(frames), objects, strict=True)]
    counts = np.array([len(m) for m in measured])
    flat = [x for m in measured for x in m]
    if not flat:
        return {"frames_with_objects": 0.0}
    return {"frames_with_objects": float((counts > 0).mean()), "objects_per_frame_with_any": float(
        counts[counts > 0].mean()), "size_m_median": float(np.median([x.size_m for x in flat])),
            "range_fraction_median": float(np.median([x.range_fraction for x in flat])),
            "highlight_median": float(np.median([x.highlight for x in flat])),
            "area_share_mean": float(np.mean([sum(x.area_share for x in m) for m in measured]))}


def classifiers(real: list[SonarImage], other: list[SonarImage], seed: int) -> dict[str, float]:
    torch.manual_seed(seed)
    grid_real = frames_on_grid(real, GRID)
    grid_other = frames_on_grid(other, GRID)
    whole = classifier_two_sample_test(grid_real, grid_other, seed=seed)
    texture = texture_two_sample_test(scaled(real), scaled(other), TextureTestConfig(seed=seed))
    # the AUC beside the accuracy: it does not depend on where the held-out scores are cut
    return {"whole_frame_accuracy": whole.accuracy, "whole_frame_auc": whole.auc,
            "texture_accuracy": texture.accuracy, "texture_auc": texture.auc}


def evenly(frames: list[SonarImage], n: int) -> list[SonarImage]:
    idx = np.linspace(0, len(frames) - 1, n).round().astype(int)
    return [frames[i] for i in idx]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibration", help="use this CALIB.json instead of calibrating first")
    parser.add_argument("--save-calibration", help="write the calibration made here to this path")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--aris", action="store_true", help="the ARIS water-tank set instead of the Oculus split")
    parser.add_argument("--against", choices=("held-out", "fit"), default="held-out",
                        help="compare with the held-out recording (the goals) or the fit recording (training side)")
    parser.add_argument("--json", help="write every figure to this JSON file")
    args = parser.parse_args()
    if args.aris and args.against == "fit":
        parser.error("--against fit: the Oculus split only (the ARIS set has one recording)")
    torch.set_num_threads(1)
    started = time.time()

    if args.aris:
        frames = load_recording(real_aris_dir() / "Images")
        fit_real, held = frames[0::2], frames[1::2]
        held = evenly(held, min(len(held), 120))
        config = CalibrateConfig(vertical_fov_deg=14.0, texture="speckle")  # the ARIS recipe (scripts/train_aris.sh)
        source = "ARIS water tank, even frames"
        annotations = read_annotations(held, [real_aris_dir() / "Masks"], parse_classes("1-10"))
    else:
        fit_real = load_recording(real_oculus_dir(), OCULUS_FIT_RECORDING)
        held = (load_recording(real_oculus_dir(), OCULUS_HELD_OUT_RECORDING) if args.against == "held-out"
                else fit_real[0::3])
        config = CalibrateConfig()
        source = f"oculus_polar_seabed [{OCULUS_FIT_RECORDING}]"
        annotations = read_annotations(held, sorted(real_oculus_dir().glob("*/labels")))
    if args.calibration:
        calibration: Calibration = load_calibration(args.calibration)
    else:
        calibration = calibrate(fit_real, source, config, log=sys.stderr).calibration
        if args.save_calibration:
            save_calibration(calibration, args.save_calibration)
    yardstick = evenly(fit_real, len(held)) if args.against == "held-out" else fit_real[1::3][:len(held)]

    real_stats = statistics(scaled(held))
    metric_held, _ = prepare_frames(held, config)  # the tables calibrate measures sizes on
    results: dict[str, dict] = {"real_fit_recording": {}, "calibrated_sim": {}}
    per_seed: dict[str, list[dict[str, float]]] = {"real_fit_recording": [], "calibrated_sim": []}
    for seed in args.seeds:
        pairs = list(simulate_calibrated(calibration, len(held), seed=1000 + seed))
        sim = [f for f, _ in pairs]
        per_seed["calibrated_sim"].append(classifiers(held, sim, seed))
        per_seed["real_fit_recording"].append(classifiers(held, yardstick, seed))
        print(f"seed {seed}: sim {per_seed['calibrated_sim'][-1]}, real {per_seed['real_fit_recording'][-1]}",
              file=sys.stderr)
        if seed == args.seeds[0]:
            sim_stats = statistics(scaled(sim))
            results["calibrated_sim"]["statistics"] = compare(sim_stats, real_stats)
            results["real_fit_recording"]["statistics"] = compare(statistics(scaled(yardstick)), real_stats)
            results["calibrated_sim"]["near_zero"] = sim_stats["near_zero"]
            results["calibrated_sim"]["targets"] = object_statistics(sim, [mask_objects(m) for _, m in pairs])
    for name, runs in per_seed.items():
        results[name]["classifiers"] = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
        results[name]["classifiers_per_seed"] = runs
    results["held_out_near_zero"] = real_stats["near_zero"]
    results["held_out_targets"] = object_statistics(metric_held, annotations.objects)
    results["setting"] = {"set": "aris" if args.aris else "oculus", "against": args.against,
                          "held_out_frames": len(held),
                          "fit_frames": len(fit_real), "seeds": args.seeds, "calibration_distances":
                          calibration.distances, "seconds": round(time.time() - started, 1),
                          "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                          "load": os.getloadavg()[0], "utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime())}
    text = json.dumps(results, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
