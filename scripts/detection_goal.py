"""The downstream detection goal (issue #12): AP@0.5 on the held-out real Oculus recording of one small detector
trained on raw simulated frames and on each translator's outputs, beside two real-frame references.

    python scripts/detection_goal.py --sim runs/sim_det \
        --model default=sonar_realism/assets/cdfcvae_default.safetensors --out runs/detection

Every frame goes onto the detector grid in bin order (`detector_image`): the real exports carry no bearing table.

Every method trains the same detector (`sonar_realism.evaluate.detection`, same config, same steps) once per seed;
the seed sets initialisation and batch order. Training boxes: the simulator's object masks (one box per object id)
for sim and translated frames, the YOLO labels for real frames. Each translator gives `--samples` samples of every
simulated input (translation seed 0), all kept as training frames: the diversity of its samples is part of what a
translator offers a detector. The score is AP@0.5 on ALL frames of the held-out recording (OCULUS_HELD_OUT_RECORDING,
its YOLO boxes); the goal is met for a translator when its mean AP beats raw sim's, and its goal line says whether
the paired per-seed difference is beyond one standard error (the detector's seed alone moves AP several-fold:
0.005 to 0.175 for raw sim on one set). Each seed trains every method with the same initialisation and batch
order, so the per-seed difference to raw sim is reported beside the means.

Two real references, never goals: the fit recording's frames (another recording, another target: how far real
frames of the sensor carry), and the held-out recording itself in two folds (train on its first half, score the
second, and the other way round; AP over all its frames): what this detector reaches on this recording's targets.

`--fit-split F` tunes without the held-out labels: the real set is the fit recording's first F of frames and
every method is scored on the rest of the fit recording (the held-out recording is not read).

AP at IoU 0.3 and 0.1 of the same detections is reported beside AP@0.5 (the simulator's masks cover a target's
lit surface, the real labels its whole echo, so box extents differ by convention; a loose IoU asks whether the
target was found at all). Markdown table on stdout, detection.json in --out (rewritten after every method, so a
run cut short keeps what it measured).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.config import from_dict, to_dict  # noqa: E402
from sonar_realism.data import (  # noqa: E402
    OCULUS_FIT_RECORDING,
    OCULUS_HELD_OUT_RECORDING,
    oculus_recording_files,
    yolo_label_file,
)
from sonar_realism.errors import ConfigError  # noqa: E402
from sonar_realism.evaluate.detection import (  # noqa: E402
    Box,
    Detection,
    DetectorConfig,
    average_precision,
    detect,
    detector_image,
    mask_boxes,
    read_yolo_boxes,
    train_detector,
)
from sonar_realism.frames import SonarImage  # noqa: E402
from sonar_realism.io import read_frames  # noqa: E402
from sonar_realism.models.cyclegan import CycleGANTranslator  # noqa: E402
from sonar_realism.models.translate import Translator, load_translator  # noqa: E402
from sonar_realism.sim.masks import frames_with_masks, mask_path  # noqa: E402

RAW = "raw sim"
REAL_FIT = "real: fit recording (reference)"
REAL_FOLDS = "real: held-out recording, 2 folds (reference)"
REFERENCES = (REAL_FIT, REAL_FOLDS)
TRANSLATION_SEED = 0
_TRANSLATE_CHUNK = 16  # inputs translated at once: bounds memory at native resolution


@dataclasses.dataclass(frozen=True)
class LabelledFrames:
    images: np.ndarray  # [N, rows, cols] float32 on the detector grid
    boxes: list[list[Box]]

    def part(self, start: int, stop: int | None = None) -> LabelledFrames:
        return LabelledFrames(self.images[start:stop], self.boxes[start:stop])


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
    ap_minus_raw_per_seed: tuple[float, ...] = ()  # the same seed's AP@0.5 less raw sim's: a paired difference

    @property
    def ap_mean(self) -> float:
        return float(np.mean(self.ap_per_seed))

    @property
    def ap_sd(self) -> float:
        return float(np.std(self.ap_per_seed, ddof=1)) if len(self.ap_per_seed) > 1 else 0.0

    @property
    def paired_difference(self) -> tuple[float, float]:
        """Mean and standard error of the per-seed difference to raw sim (the detector's seed alone moves a
        method's AP several-fold: a goal met by less than this error is not a shown gain)."""
        paired = np.asarray(self.ap_minus_raw_per_seed, np.float64)
        error = float(paired.std(ddof=1) / np.sqrt(paired.size)) if paired.size > 1 else float("inf")
        return float(paired.mean()), error


def real_labelled(recording: str, grid: tuple[int, int], data: str | None) -> LabelledFrames:
    files = oculus_recording_files(recording, data)
    if not files:
        raise SystemExit(f"no frames of {recording}: set SONAR_REALISM_DATA or pass --data")
    images = [detector_image(frame, grid) for path in files for frame in read_frames(path)]
    if len(images) != len(files):
        raise ConfigError(f"{recording}: {len(files)} image files gave {len(images)} frames; expected one each")
    return LabelledFrames(np.stack(images), [read_yolo_boxes(yolo_label_file(path), grid) for path in files])


def simulated_with_masks(folder: Path) -> tuple[list[SonarImage], list[np.ndarray]]:
    frames, masks = [], []
    for index, (frame, mask) in enumerate(frames_with_masks(folder)):
        if mask is None:
            raise ConfigError(f"{mask_path(folder, index)}: missing object mask (write the folder with "
                              "`sonar-realism simulate`)")
        frames.append(frame)
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
                images.append(detector_image(output.sample(k), grid))
                labels.append(frame_boxes)
    return LabelledFrames(np.stack(images), labels)


def score(method: str, folds: list[tuple[LabelledFrames, range]], scored: LabelledFrames, config: DetectorConfig,
          seeds: list[int], raw: MethodResult | None = None) -> MethodResult:
    """Train on each fold's training frames, detect on its frames of `scored` (a range of indices), and score
    the detections of all folds together, once per seed."""
    started = time.monotonic()
    aps: dict[float, list[float]] = {0.5: [], 0.3: [], 0.1: []}
    for seed in seeds:
        predictions: list[list[Detection]] = [[] for _ in scored.boxes]
        for training, indices in folds:
            detector = train_detector(training.images, training.boxes, dataclasses.replace(config, seed=seed))
            for index, found in zip(indices, detect(detector, scored.images[indices.start:indices.stop]), strict=True):
                predictions[index] = found
        for iou, values in aps.items():
            values.append(average_precision(predictions, scored.boxes, iou=iou))
        print(f"  {method} seed {seed}: AP@0.5 {aps[0.5][-1]:.3f}, AP@0.3 {aps[0.3][-1]:.3f}, AP@0.1 "
              f"{aps[0.1][-1]:.3f} ({time.monotonic() - started:.0f} s)", file=sys.stderr)
    paired = tuple(ap - raw_ap for ap, raw_ap in zip(aps[0.5], raw.ap_per_seed, strict=True)) if raw else ()
    training_frames = sum(len(training.images) for training, _ in folds) // len(folds)
    training_boxes = sum(sum(len(b) for b in training.boxes) for training, _ in folds) // len(folds)
    return MethodResult(method, training_frames, training_boxes, tuple(aps[0.5]), tuple(aps[0.3]), tuple(aps[0.1]),
                        time.monotonic() - started, paired)


def markdown(results: list[MethodResult], seeds: list[int]) -> str:
    lines = ["| method | training frames (boxes) | AP@0.5 mean ± sd | "
             + " | ".join(f"AP@0.5 seed {s}" for s in seeds)
             + " | AP@0.5 − raw sim, same seed: mean (seeds above 0) | AP@0.3 mean | AP@0.1 mean |",
             "|---|---:|---:|" + "---:|" * (len(seeds) + 3)]
    for result in results:
        paired = result.ap_minus_raw_per_seed
        difference = (f"{np.mean(paired):+.3f} ({sum(d > 0 for d in paired)}/{len(paired)})" if paired else "–")
        lines.append(f"| {result.method} | {result.training_frames} ({result.training_boxes}) "
                     f"| {result.ap_mean:.3f} ± {result.ap_sd:.3f} | "
                     + " | ".join(f"{ap:.3f}" for ap in result.ap_per_seed)
                     + f" | {difference} | {np.mean(result.ap_iou30_per_seed):.3f} "
                     f"| {np.mean(result.ap_iou10_per_seed):.3f} |")
    return "\n".join(lines)


def goal_lines(results: list[MethodResult]) -> list[str]:
    raw = next(r for r in results if r.method == RAW)
    lines = []
    for r in results:
        if r.method in (RAW, *REFERENCES):
            continue
        difference, error = r.paired_difference
        lines.append(f"goal ({r.method} > {RAW}): {'met' if r.ap_mean > raw.ap_mean else 'NOT met'} "
                     f"({r.ap_mean:.3f} vs {raw.ap_mean:.3f}; paired difference {difference:+.3f} ± {error:.3f} "
                     f"s.e. over {len(r.ap_minus_raw_per_seed)} seeds: "
                     f"{'beyond' if abs(difference) > error else 'within'} one standard error)")
    return lines


def detector_config(settings: list[str]) -> DetectorConfig:
    """DetectorConfig from KEY=VALUE settings (VALUE as JSON: 3, 1.5, [1, 2]); unknown keys are rejected."""
    pairs = [setting.partition("=") for setting in settings]
    if any(not key or not sep for key, sep, _ in pairs):
        raise ConfigError(f"--detector: expected KEY=VALUE, got {settings}")
    try:
        values = {key: json.loads(value) for key, _, value in pairs}
    except json.JSONDecodeError as error:
        raise ConfigError(f"--detector: a value is not JSON ({error.msg}) in {settings}") from error
    return from_dict(DetectorConfig, values, where="--detector")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim", required=True, type=Path, help="simulated frames with masks/ (sonar-realism simulate)")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=CKPT",
                        help="translator checkpoint (repeatable)")
    parser.add_argument("--samples", type=int, default=2, help="translated samples per simulated input (default 2)")
    parser.add_argument("--detector", action="append", default=[], metavar="KEY=VALUE",
                        help="a DetectorConfig field (repeatable), e.g. steps=2000 max_zoom=3")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--fit-split", type=float, metavar="F",
                        help="tune: train the real set on the fit recording's first F, score every method on the "
                             "rest (the held-out recording is not read)")
    parser.add_argument("--data", help="data folder (default: $SONAR_REALISM_DATA or ../shared/data)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1: a shared machine)")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args()
    if args.samples < 1:
        raise ConfigError(f"--samples: need at least 1, got {args.samples}")
    if args.fit_split is not None and not 0 < args.fit_split < 1:
        raise ConfigError(f"--fit-split: a fraction in (0, 1), got {args.fit_split}")
    models = [spec.partition("=") for spec in args.model]
    if any(not name or not path for name, _, path in models):
        raise ConfigError(f"--model: expected NAME=CKPT, got {args.model}")
    torch.set_num_threads(args.threads)
    config = detector_config(args.detector)
    grid = config.grid
    started = time.monotonic()
    args.out.mkdir(parents=True, exist_ok=True)

    fit = real_labelled(OCULUS_FIT_RECORDING, grid, args.data)
    if args.fit_split is None:
        scored_name, scored = OCULUS_HELD_OUT_RECORDING, real_labelled(OCULUS_HELD_OUT_RECORDING, grid, args.data)
    else:
        cut = round(args.fit_split * len(fit.images))
        scored_name, scored, fit = f"{OCULUS_FIT_RECORDING}[{cut}:]", fit.part(cut), fit.part(0, cut)
    everything = range(len(scored.images))
    sim_frames, masks = simulated_with_masks(args.sim)
    sim_boxes = [mask_boxes(mask, frame, grid) for mask, frame in zip(masks, sim_frames, strict=True)]
    raw = LabelledFrames(np.stack([detector_image(f, grid) for f in sim_frames]), sim_boxes)
    print(f"data ready: {len(sim_frames)} sim frames, {len(fit.images)} fit, {len(scored.images)} scored "
          f"({time.monotonic() - started:.0f} s)", file=sys.stderr)

    results: list[MethodResult] = []

    def record() -> dict[str, object]:
        return {"scored_recording": scored_name, "scored_frames": len(scored.images),
                "scored_boxes": sum(len(b) for b in scored.boxes), "fit_recording": OCULUS_FIT_RECORDING,
                "fit_frames": len(fit.images), "fit_split": args.fit_split,
                "sim": str(args.sim), "sim_frames": len(sim_frames), "samples_per_input": args.samples,
                "translation_seed": TRANSLATION_SEED, "iou": 0.5, "seeds": args.seeds, "detector": to_dict(config),
                "methods": [{**dataclasses.asdict(r), "ap_mean": r.ap_mean, "ap_sd": r.ap_sd} for r in results],
                "command": " ".join(sys.argv), "machine": platform.processor() or platform.machine(),
                "threads": args.threads, "seconds": time.monotonic() - started}

    def add(result: MethodResult) -> MethodResult:
        results.append(result)
        (args.out / "detection.json").write_text(json.dumps(record(), indent=1) + "\n", encoding="utf-8")
        return result

    raw_result = add(score(RAW, [(raw, everything)], scored, config, args.seeds))
    for name, _, path in models:
        translator = load_translator(path, "cpu")
        outputs = translated(translator, sim_frames, sim_boxes, args.samples, grid)
        print(f"{name}: translated {len(outputs.images)} frames ({time.monotonic() - started:.0f} s)", file=sys.stderr)
        add(score(name, [(outputs, everything)], scored, config, args.seeds, raw_result))
    add(score(REAL_FIT, [(fit, everything)], scored, config, args.seeds, raw_result))
    if args.fit_split is None:
        half = len(scored.images) // 2
        first, second = range(0, half), range(half, len(scored.images))
        add(score(REAL_FOLDS, [(scored.part(half), first), (scored.part(0, half), second)], scored, config,
                  args.seeds, raw_result))

    print(markdown(results, args.seeds))
    print()
    print("\n".join(goal_lines(results)))
    print(f"\n{time.monotonic() - started:.0f} s in all; detection.json in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
