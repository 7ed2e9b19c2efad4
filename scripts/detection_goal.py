"""The downstream detection goal (issue #12): AP@0.5 on the held-out real Oculus recording of one small detector
trained on raw simulated frames, on each translator's outputs, and (the ceiling) on the fit recording's real frames.

    python scripts/detection_goal.py --sim runs/sim_det \
        --model default=sonar_realism/assets/cdfcvae_default.safetensors --out runs/detection

Every method trains the same detector (`sonar_realism.evaluate.detection`, same config, same steps) once per seed;
the seed sets initialisation and batch order. Training boxes: the simulator's object masks (one box per object id)
for sim and translated frames, the YOLO labels for real frames. Each translator gives `--samples` samples of every
simulated input (translation seed 0), all kept as training frames: the diversity of its samples is part of what a
translator offers a detector. The score is AP@0.5 on ALL frames of the held-out recording (OCULUS_HELD_OUT_RECORDING,
its YOLO boxes); the goal is met for a translator when its mean AP beats raw sim's. AP at IoU 0.3 and 0.1 of the
same detections is reported beside it (the simulator's masks cover a target's lit surface, the real labels its
whole echo, so box extents differ by convention; a loose IoU asks whether the target was found at all).
Markdown table on stdout, detection.json in --out (rewritten after every method, so a run cut short keeps what it
measured).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.config import to_dict  # noqa: E402
from sonar_realism.data import (  # noqa: E402
    OCULUS_FIT_RECORDING,
    OCULUS_HELD_OUT_RECORDING,
    oculus_recording_files,
    yolo_label_file,
)
from sonar_realism.errors import ConfigError  # noqa: E402
from sonar_realism.evaluate.detection import (  # noqa: E402
    Box,
    DetectorConfig,
    average_precision,
    detect,
    mask_boxes,
    read_yolo_boxes,
    train_detector,
)
from sonar_realism.frames import SonarImage  # noqa: E402
from sonar_realism.io import read_frames  # noqa: E402
from sonar_realism.models.cyclegan import CycleGANTranslator  # noqa: E402
from sonar_realism.models.datasets import to_model_grid  # noqa: E402
from sonar_realism.models.translate import Translator, load_translator  # noqa: E402

RAW = "raw sim"
REAL_FIT = "real (fit recording), ceiling"
TRANSLATION_SEED = 0
_TRANSLATE_CHUNK = 16  # inputs translated at once: bounds memory at native resolution


@dataclasses.dataclass(frozen=True)
class LabelledFrames:
    images: np.ndarray  # [N, rows, cols] float32 on the detector grid
    boxes: list[list[Box]]


@dataclasses.dataclass(frozen=True)
class MethodResult:
    method: str
    training_frames: int
    training_boxes: int
    ap_per_seed: tuple[float, ...]  # at IoU 0.5: the goal's score
    # Same detections, looser IoU: does the detector find the targets at all, whatever their box's extent?
    # (The simulator's masks cover the lit surface of a target; the real labels frame the whole echo.)
    ap_iou30_per_seed: tuple[float, ...]
    ap_iou10_per_seed: tuple[float, ...]
    seconds: float

    @property
    def ap_mean(self) -> float:
        return float(np.mean(self.ap_per_seed))

    @property
    def ap_sd(self) -> float:
        return float(np.std(self.ap_per_seed, ddof=1)) if len(self.ap_per_seed) > 1 else 0.0


def real_labelled(recording: str, grid: tuple[int, int], data: str | None) -> LabelledFrames:
    files = oculus_recording_files(recording, data)
    if not files:
        raise SystemExit(f"no frames of {recording}: set SONAR_REALISM_DATA or pass --data")
    images = [to_model_grid(frame, grid, "frame_max") for path in files for frame in read_frames(path)]
    if len(images) != len(files):
        raise ConfigError(f"{recording}: {len(files)} image files gave {len(images)} frames; expected one each")
    return LabelledFrames(np.stack(images), [read_yolo_boxes(yolo_label_file(path), grid) for path in files])


def simulated_with_masks(folder: Path) -> tuple[list[SonarImage], list[np.ndarray]]:
    frames = list(read_frames(folder))
    masks = []
    for index in range(len(frames)):
        path = folder / "masks" / f"{index:06d}.png"
        mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if mask is None:
            raise ConfigError(f"{path}: missing or unreadable object mask (write the folder with "
                              "`sonar-realism simulate`)")
        masks.append(mask)
    return frames, masks


def translated(translator: Translator | CycleGANTranslator, frames: list[SonarImage], boxes: list[list[Box]],
               samples: int, grid: tuple[int, int]) -> LabelledFrames:
    images, labels = [], []
    for start in range(0, len(frames), _TRANSLATE_CHUNK):
        chunk = frames[start:start + _TRANSLATE_CHUNK]
        # One seed for the whole set, chunk by chunk: offsetting it keeps chunks' noise independent.
        for output, frame_boxes in zip(translator.translate(chunk, n=samples, seed=TRANSLATION_SEED + start),
                                       boxes[start:start + _TRANSLATE_CHUNK], strict=True):
            for k in range(samples):
                images.append(to_model_grid(output.sample(k), grid, "frame_max"))
                labels.append(frame_boxes)
    return LabelledFrames(np.stack(images), labels)


def score(method: str, training: LabelledFrames, held_out: LabelledFrames, config: DetectorConfig,
          seeds: list[int]) -> MethodResult:
    started = time.monotonic()
    aps: dict[float, list[float]] = {0.5: [], 0.3: [], 0.1: []}
    for seed in seeds:
        detector = train_detector(training.images, training.boxes, dataclasses.replace(config, seed=seed))
        predictions = detect(detector, held_out.images)
        for iou, values in aps.items():
            values.append(average_precision(predictions, held_out.boxes, iou=iou))
        print(f"  {method} seed {seed}: AP@0.5 {aps[0.5][-1]:.3f}, AP@0.3 {aps[0.3][-1]:.3f}, AP@0.1 "
              f"{aps[0.1][-1]:.3f} ({time.monotonic() - started:.0f} s)", file=sys.stderr)
    return MethodResult(method, len(training.images), sum(len(b) for b in training.boxes), tuple(aps[0.5]),
                        tuple(aps[0.3]), tuple(aps[0.1]),
                        time.monotonic() - started)


def markdown(results: list[MethodResult], seeds: list[int]) -> str:
    lines = ["| method | training frames (boxes) | AP@0.5 mean ± sd | "
             + " | ".join(f"AP@0.5 seed {s}" for s in seeds) + " | AP@0.3 mean | AP@0.1 mean |",
             "|---|---:|---:|" + "---:|" * (len(seeds) + 2)]
    for result in results:
        lines.append(f"| {result.method} | {result.training_frames} ({result.training_boxes}) "
                     f"| {result.ap_mean:.3f} ± {result.ap_sd:.3f} | "
                     + " | ".join(f"{ap:.3f}" for ap in result.ap_per_seed)
                     + f" | {np.mean(result.ap_iou30_per_seed):.3f} | {np.mean(result.ap_iou10_per_seed):.3f} |")
    return "\n".join(lines)


def goal_lines(results: list[MethodResult]) -> list[str]:
    raw = next(r for r in results if r.method == RAW)
    return [f"goal ({r.method} > {RAW}): {'met' if r.ap_mean > raw.ap_mean else 'NOT met'} "
            f"({r.ap_mean:.3f} vs {raw.ap_mean:.3f})" for r in results if r.method not in (RAW, REAL_FIT)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim", required=True, type=Path, help="simulated frames with masks/ (sonar-realism simulate)")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=CKPT",
                        help="translator checkpoint (repeatable)")
    parser.add_argument("--samples", type=int, default=2, help="translated samples per simulated input (default 2)")
    parser.add_argument("--steps", type=int, default=DetectorConfig.steps, help="detector training steps")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--data", help="data folder (default: $SONAR_REALISM_DATA or ../shared/data)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1: a shared machine)")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args()
    if args.samples < 1:
        raise ConfigError(f"--samples: need at least 1, got {args.samples}")
    models = [spec.partition("=") for spec in args.model]
    if any(not name or not path for name, _, path in models):
        raise ConfigError(f"--model: expected NAME=CKPT, got {args.model}")
    torch.set_num_threads(args.threads)
    config = DetectorConfig(steps=args.steps)
    grid = config.grid
    started = time.monotonic()
    args.out.mkdir(parents=True, exist_ok=True)

    held_out = real_labelled(OCULUS_HELD_OUT_RECORDING, grid, args.data)
    fit = real_labelled(OCULUS_FIT_RECORDING, grid, args.data)
    sim_frames, masks = simulated_with_masks(args.sim)
    sim_boxes = [mask_boxes(mask, frame, grid) for mask, frame in zip(masks, sim_frames, strict=True)]
    raw = LabelledFrames(np.stack([to_model_grid(f, grid, "frame_max") for f in sim_frames]), sim_boxes)
    print(f"data ready: {len(sim_frames)} sim frames, {len(fit.images)} fit, {len(held_out.images)} held-out "
          f"({time.monotonic() - started:.0f} s)", file=sys.stderr)

    results: list[MethodResult] = []

    def record() -> dict[str, object]:
        return {"held_out_recording": OCULUS_HELD_OUT_RECORDING, "held_out_frames": len(held_out.images),
                "held_out_boxes": sum(len(b) for b in held_out.boxes), "fit_recording": OCULUS_FIT_RECORDING,
                "sim": str(args.sim), "sim_frames": len(sim_frames), "samples_per_input": args.samples,
                "translation_seed": TRANSLATION_SEED, "iou": 0.5, "seeds": args.seeds, "detector": to_dict(config),
                "methods": [{**dataclasses.asdict(r), "ap_mean": r.ap_mean, "ap_sd": r.ap_sd} for r in results],
                "command": " ".join(sys.argv), "machine": platform.processor() or platform.machine(),
                "threads": args.threads, "seconds": time.monotonic() - started}

    def add(result: MethodResult) -> None:
        results.append(result)
        (args.out / "detection.json").write_text(json.dumps(record(), indent=1) + "\n", encoding="utf-8")

    add(score(RAW, raw, held_out, config, args.seeds))
    for name, _, path in models:
        translator = load_translator(path, "cpu")
        outputs = translated(translator, sim_frames, sim_boxes, args.samples, grid)
        print(f"{name}: translated {len(outputs.images)} frames ({time.monotonic() - started:.0f} s)", file=sys.stderr)
        add(score(name, outputs, held_out, config, args.seeds))
    add(score(REAL_FIT, fit, held_out, config, args.seeds))

    print(markdown(results, args.seeds))
    print()
    print("\n".join(goal_lines(results)))
    print(f"\n{time.monotonic() - started:.0f} s in all; detection.json in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
