"""Measure the translator goals (issue #12) on a held-out real recording (by default the Oculus one); Markdown
table + JSON.

    python scripts/translator_goals.py --sim runs/sim_plain/organic --sim runs/sim_plain/constructed \
        --model default=sonar_realism/assets/cdfcvae_default.safetensors \
        --model paper=sonar_realism/assets/cdfcvae_paper.safetensors --out runs/goals

Real frames: the held-out recording (OCULUS_HELD_OUT_RECORDING, never trained on) is the reference; the
fit recording gives the real-vs-real yardstick of both two-sample tests, measured in the same run. Another
sensor: `--held-out DIR --yardstick DIR` (e.g. the ARIS split of scripts/aris_split.py). Each
two-sample test is repeated over `--seeds` (patch positions, classifier init) and averaged: on 89 frames one
run moves by up to +-0.2, so the default is 8 seeds. Simulated inputs are read from folders written by
`sonar-realism simulate` (object masks from their masks/ folder). Every method is scored on the same inputs:
- texture two-sample accuracy (32 x 32 native-resolution patches, level removed) and whole-frame two-sample
  accuracy (128 x 128 model grid), first sample of each input;
- speckle contrast and K shape per range band (model grid), grain (lag-1 correlation along range and across
  beams, native resolution), relative to the held-out real recording; the texture's range asymmetry
  (evaluate.texture.range_asymmetry, native), beside the held-out recording's;
- diversity: per-pixel std over `--n` samples of one input / per-pixel std between inputs (native);
- structure: object-mask IoU of the output over that of the input, edge SSIM of the posterior mean
  (temperature 0) against the input.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.data import (  # noqa: E402
    OCULUS_FIT_RECORDING,
    OCULUS_HELD_OUT_RECORDING,
    oculus_recording_files,
)
from sonar_realism.evaluate.diversity import sample_diversity  # noqa: E402
from sonar_realism.evaluate.structure import edge_ssim, mask_iou, mask_to_grid  # noqa: E402
from sonar_realism.evaluate.texture import grain, range_asymmetry, speckle_statistics  # noqa: E402
from sonar_realism.evaluate.two_sample import (  # noqa: E402
    TextureTestConfig,
    classifier_two_sample_test,
    texture_two_sample_test,
)
from sonar_realism.frames import SonarImage  # noqa: E402
from sonar_realism.io import read_frames  # noqa: E402
from sonar_realism.models.datasets import frames_on_grid, normalise, to_model_grid  # noqa: E402
from sonar_realism.models.translate import load_translator  # noqa: E402
from sonar_realism.sim.masks import read_mask  # noqa: E402

GRID = (128, 128)
RAW = "raw sim"
REAL_FIT = "real (fit recording)"


def real_frames(recording: str, every: int = 1) -> list[SonarImage]:
    files = oculus_recording_files(recording)[::every]
    if not files:
        raise SystemExit(f"no frames of {recording}: set SONAR_REALISM_DATA to the data folder")
    return [frame for path in files for frame in read_frames(path)]


def folder_frames(path: str, limit: int) -> list[SonarImage]:
    frames = list(read_frames(path))
    return [frames[i] for i in np.linspace(0, len(frames) - 1, min(limit, len(frames))).astype(int)]


def sim_inputs(folders: list[str], per_folder: int) -> tuple[list[SonarImage], list[np.ndarray | None]]:
    frames, masks = [], []
    for folder in folders:
        loaded = list(read_frames(folder))
        for index in np.linspace(0, len(loaded) - 1, min(per_folder, len(loaded))).astype(int):
            frames.append(loaded[index])
            masks.append(read_mask(folder, int(index), loaded[index]))
    return frames, masks


def two_sample(real: list[np.ndarray], generated: list[np.ndarray], real_grid: np.ndarray,
               generated_grid: np.ndarray, seeds: list[int]) -> dict[str, float]:
    # accuracy (the measure) and the AUC of the same held-out scores, per seed and averaged
    texture = [texture_two_sample_test(real, generated, TextureTestConfig(seed=s)) for s in seeds]
    whole = [classifier_two_sample_test(real_grid, generated_grid, seed=s) for s in seeds]
    return {"texture_accuracy": float(np.mean([t.accuracy for t in texture])),
            "texture_runs": [t.accuracy for t in texture], "texture_auc": float(np.mean([t.auc for t in texture])),
            "texture_auc_runs": [t.auc for t in texture],
            "whole_frame_accuracy": float(np.mean([w.accuracy for w in whole])),
            "whole_frame_runs": [w.accuracy for w in whole], "whole_frame_auc": float(np.mean([w.auc for w in whole])),
            "whole_frame_auc_runs": [w.auc for w in whole]}


def texture_statistics(native: list[np.ndarray], grid: np.ndarray) -> dict[str, float]:
    bands = speckle_statistics(grid)
    g = grain(native)
    return {"contrast": float(np.nanmean([b.contrast for b in bands])),
            "k_shape": float(np.nanmean([b.k_shape for b in bands])),
            "grain_range": g.along_range, "grain_beams": g.across_beams,
            "range_asymmetry": range_asymmetry(native)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim", action="append", required=True, help="simulated frames folder (repeatable)")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=CKPT", help="translator (repeatable)")
    parser.add_argument("--per-folder", type=int, default=45, help="inputs taken from each --sim folder")
    parser.add_argument("--n", type=int, default=8, help="samples per input")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(8)),
                        help="two-sample test seeds (one run moves by up to +-0.2: 3 were too few)")
    parser.add_argument("--out", required=True)
    parser.add_argument("--resume", action="store_true", help="keep the methods already in OUT/goals.json")
    parser.add_argument("--held-out", help="real frames no translator trained on (any read_frames input; default: "
                                           "the held-out Oculus recording)")
    parser.add_argument("--yardstick", help="real frames of the fit recording(s), for the real-vs-real yardstick "
                                            "(default: the fit Oculus recording, every 3rd frame)")
    parser.add_argument("--max-real", type=int, default=300, help="at most this many frames of --held-out and "
                                                                  "--yardstick each, evenly spaced")
    args = parser.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    started = time.monotonic()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    held = folder_frames(args.held_out, args.max_real) if args.held_out else real_frames(OCULUS_HELD_OUT_RECORDING)
    fit = folder_frames(args.yardstick, args.max_real) if args.yardstick else real_frames(OCULUS_FIT_RECORDING, 3)
    held_native = [normalise(f, "frame_max") for f in held]
    held_grid = frames_on_grid(held, GRID)
    inputs, masks = sim_inputs(args.sim, args.per_folder)
    input_grid = frames_on_grid(inputs, GRID)

    results: dict[str, dict[str, object]] = {}
    previous = out / "goals.json"
    if args.resume and previous.is_file():  # keep what an earlier run of the same command measured
        results = json.loads(previous.read_text())["methods"]
    real_stats = texture_statistics(held_native, held_grid)
    if REAL_FIT not in results:
        fit_native = [normalise(f, "frame_max") for f in fit]
        fit_grid = frames_on_grid(fit, GRID)
        results[REAL_FIT] = {**two_sample(held_native, fit_native, held_grid, fit_grid, args.seeds),
                             **texture_statistics(fit_native, fit_grid)}
    print(f"yardstick done ({time.monotonic() - started:.0f} s)", file=sys.stderr)

    def measure(outputs: list[SonarImage], means: list[SonarImage]) -> dict[str, object]:
        first_native = [normalise(f.sample(0), "frame_max") for f in outputs]
        first_grid = frames_on_grid([f.sample(0) for f in outputs], GRID)
        row: dict[str, object] = {**two_sample(held_native, first_native, held_grid, first_grid, args.seeds),
                                  **texture_statistics(first_native, first_grid)}
        if outputs[0].intensity.shape[0] >= 2:
            # the most common native grid (a calibrated sim varies its range bins), up to 16 inputs of it
            shapes = [f.intensity.shape for f in outputs]
            common = max(set(shapes), key=shapes.count)
            stack = np.stack([normalise(f, "frame_max") for f in outputs if f.intensity.shape == common][:16])
            row["diversity"] = dataclasses.asdict(sample_diversity(stack))
        ious, input_ious = [], []
        for mask, frame, output, source in zip(masks, inputs, first_grid, input_grid, strict=True):
            if mask is not None and mask.any():
                on_grid = mask_to_grid(mask, frame, GRID)
                ious.append(mask_iou(on_grid, output, source))
                input_ious.append(mask_iou(on_grid, source))
        # the ratio is the goal; the two IoUs beside it say whether the input itself showed its objects
        row.update(mask_iou=None, mask_iou_input=None, mask_iou_ratio=None)
        if ious:
            iou, input_iou = float(np.nanmean(ious)), float(np.nanmean(input_ious))
            row.update(mask_iou=iou, mask_iou_input=input_iou, mask_iou_ratio=iou / input_iou)
        mean_grid = [to_model_grid(f, GRID, "frame_max") for f in means]
        row["edge_ssim_mean"] = float(np.mean([edge_ssim(a, b) for a, b in zip(input_grid, mean_grid,
                                                                              strict=True)]))
        return row

    def record() -> dict[str, object]:
        return {"real_held_out": real_stats, "methods": results, "n_inputs": len(inputs), "n_held_out": len(held),
                "n_fit_yardstick": len(fit), "seeds": args.seeds, "command": " ".join(sys.argv),
                "seconds": time.monotonic() - started}

    # written after every method, so a long run that is cut short keeps what it measured
    if RAW not in results:
        results[RAW] = measure([f.replace(intensity=f.intensity[None]) for f in inputs], inputs)
        (out / "goals.json").write_text(json.dumps(record(), indent=1) + "\n")
    print(f"{RAW} done ({time.monotonic() - started:.0f} s)", file=sys.stderr)
    for spec in args.model:
        name, _, path = spec.partition("=")
        if name in results:
            continue
        translator = load_translator(path, "cpu")
        outputs = translator.translate(inputs, n=args.n, seed=0)
        means = [f.sample(0) for f in translator.translate(inputs, n=1, temperature=0.0, seed=0)]
        results[name] = measure(outputs, means)
        (out / "goals.json").write_text(json.dumps(record(), indent=1) + "\n")
        print(f"{name} done ({time.monotonic() - started:.0f} s)", file=sys.stderr)

    print(markdown(record()))
    return 0


def markdown(record: dict) -> str:
    real = record["real_held_out"]
    lines = ["| method | texture 2-sample: accuracy (AUC), per seed | whole-frame 2-sample: accuracy (AUC), per seed "
             "| contrast / real | K shape / real "
             "| grain range / real | grain beams / real | range asymmetry (real's) | diversity (std ratio) "
             "| mask IoU / input's | edge SSIM (mean) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, row in record["methods"].items():
        diversity = row.get("diversity")
        lines.append(
            f"| {name} | {_runs(row, 'texture')} | {_runs(row, 'whole_frame')} "
            f"| {row['contrast'] / real['contrast']:.2f} | {row['k_shape'] / real['k_shape']:.2f} "
            f"| {row['grain_range'] / real['grain_range']:.2f} | {row['grain_beams'] / real['grain_beams']:.2f} "
            f"| {row.get('range_asymmetry', float('nan')):+.2f} ({real.get('range_asymmetry', float('nan')):+.2f}) "
            f"| {diversity['std_ratio'] if diversity else float('nan'):.2f} "
            f"| {row.get('mask_iou_ratio') or float('nan'):.2f} | {row.get('edge_ssim_mean', float('nan')):.2f} |")
    return "\n".join(lines)


def _runs(row: dict, test: str) -> str:
    """'mean (AUC mean): per-seed accuracies' (rows of an older goals.json have no AUC)."""
    runs = " / ".join(f"{value:.2f}" for value in row[f"{test}_runs"])
    auc = f" ({row[f'{test}_auc']:.2f})" if f"{test}_auc" in row else ""
    return f"**{row[f'{test}_accuracy']:.2f}**{auc}: {runs}"


if __name__ == "__main__":
    raise SystemExit(main())
