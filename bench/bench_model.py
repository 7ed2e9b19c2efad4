"""cDFCVAE translation speed: ms per input frame and samples/s for n = 1, 4, 16 at 128 × 128 and 256 beams ×
512 ranges, against the CycleGAN generator (stock ResNet-9, one output per frame) at the same size.

    python bench/bench_model.py            (or: python bench/run.py model)
    python bench/bench_model.py --diversity   (sample diversity with 0, 2, 3 skip connections; trains small models)

A row times `Translator.translate([frame], n)` end to end for one frame of the given size, i.e. the
streaming case of one ping at a time, with the checkpoints as shipped: the frame is resampled to the model's
grid (128 x 128 for both), encoded once, n latents decoded (the shipped model decodes its mean field at half
that grid), the samples resampled back onto the frame's own ranges and bearings, and the shipped model's
speckle layer drawn at the frame's own resolution. The paper configuration (sonar_realism/assets/
cdfcvae_paper.*) runs beside it at n = 4; the ratio column is time against the CycleGAN generator run at the
frame's full size in the same block, so a busy machine hurts all alike. Goals (issue 12): >= 40 frames/s at
128 × 128 and >= 10 frames/s at 512 × 256, n = 4, CPU. With CUDA available, GPU rows are added, and the GPU
goals are timed: >= 20 000 samples/s at 128 × 128 (a batch of 64 frames, n = 16 each, so the chip is filled)
and >= 40 frames/s with n = 16 at 512 × 512 (one frame at a time). `--device cpu|cuda` times one device only.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.data import real_oculus_dir  # noqa: E402
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges  # noqa: E402
from sonar_realism.models.cdfcvae import CDFCVAEConfig  # noqa: E402
from sonar_realism.models.translate import DEFAULT_CHECKPOINT, Translator  # noqa: E402

GRIDS = ((128, 128), (512, 256))  # (n_ranges, n_beams)
SAMPLES = (1, 4, 16)
GOAL_FPS_N4 = {(128, 128): 40.0, (512, 256): 10.0}
# (grid, frames per call, n, goal, unit): the GPU goals of issue 12.
GPU_GOALS = (((128, 128), 64, 16, 20_000.0, "samples/s"), ((512, 512), 1, 16, 40.0, "frames/s"))
PAPER_CHECKPOINT = DEFAULT_CHECKPOINT.with_name("cdfcvae_paper.safetensors")


def _timed(fn: Callable[[], object], repeats: int) -> float:
    """Median seconds of `repeats` calls after one warm-up."""
    fn()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def _cyclegan_generator() -> torch.nn.Module | None:
    try:
        from sonar_realism.models.cyclegan import ResnetGenerator
    except ImportError:
        return None
    return ResnetGenerator().eval()


def _cyclegan_seconds(generator: torch.nn.Module, n_frames: int, grid: tuple[int, int], device: str,
                      repeats: int) -> float:
    """Median seconds of the CycleGAN generator on `n_frames` random frames of `grid`, on `device`."""
    g = generator.to(device)
    x = torch.rand(n_frames, 1, *grid, device=device) * 2 - 1

    def step() -> None:
        with torch.inference_mode():
            g(x)
        if device == "cuda":
            torch.cuda.synchronize()

    return _timed(step, repeats)


def _frame(grid: tuple[int, int]) -> SonarImage:
    rng = np.random.default_rng(0)
    return SonarImage(rng.integers(0, 255, grid, dtype=np.uint8), uniform_ranges(grid[0], 30.0),
                      uniform_azimuths(grid[1], np.radians(130)))


def _label(translator: Translator, name: str) -> str:
    cfg = translator.model.cfg
    return f"{name} {'-'.join(map(str, cfg.widths))} @ {cfg.grid[0]}x{cfg.grid[1]}"


def run(devices: tuple[str, ...] | None = None) -> list[dict]:
    torch.set_num_threads(max(1, torch.get_num_threads()))
    devices = devices or ("cpu",) + (("cuda",) if torch.cuda.is_available() else ())
    generator = _cyclegan_generator()
    rows = []
    for device in devices:
        translators = [(_label(t, name), t) for name, t in (
            ("shipped", Translator.from_checkpoint(DEFAULT_CHECKPOINT, device=device)),
            ("paper", Translator.from_checkpoint(PAPER_CHECKPOINT, device=device)))]
        for grid in GRIDS:
            frame = _frame(grid)
            repeats = 8 if grid == (128, 128) else 3
            cyclegan_s = None if generator is None else _cyclegan_seconds(generator, 1, grid, device, repeats)
            for label, translator in translators:
                for n in SAMPLES if label.startswith("shipped") else (4,):
                    seconds = _timed(lambda t=translator, n=n, f=frame: t.translate([f], n, seed=0), repeats)
                    row = {"device": device, "frame (R x B)": f"{grid[0]}x{grid[1]}", "checkpoint": label, "n": n,
                           "ms/frame": 1e3 * seconds, "frames/s": 1.0 / seconds, "samples/s": n / seconds}
                    if cyclegan_s is not None:
                        row["cyclegan ms/frame"] = 1e3 * cyclegan_s
                        row["time vs cyclegan"] = seconds / cyclegan_s
                    else:
                        row["cyclegan ms/frame"] = "n/a (sonar_realism.models.cyclegan missing)"
                    if device == "cpu" and n == 4:
                        goal = GOAL_FPS_N4[grid]
                        row["goal"] = f"{goal:g} frames/s: {'met' if 1.0 / seconds >= goal else 'missed'}"
                    rows.append(row)
                    print(row, file=sys.stderr)
    if "cuda" in devices:
        rows.extend(gpu_goal_rows(generator))
    return rows


def gpu_goal_rows(generator: torch.nn.Module | None) -> list[dict]:
    """The issue's GPU goals, end to end as `translate` runs them (frames in, frames with texture out), beside the
    CycleGAN generator on the same batch of full-size frames."""
    rows = []
    for name, checkpoint in (("shipped", DEFAULT_CHECKPOINT), ("paper", PAPER_CHECKPOINT)):
        translator = Translator.from_checkpoint(checkpoint, device="cuda")
        for grid, n_frames, n, goal, unit in GPU_GOALS:
            frames = [_frame(grid)] * n_frames
            seconds = _timed(lambda t=translator, f=frames, n=n: t.translate(f, n, seed=0), 5)
            rate = (n_frames * n if unit == "samples/s" else n_frames) / seconds
            row = {"device": "cuda", "frame (R x B)": f"{grid[0]}x{grid[1]}", "checkpoint": _label(translator, name),
                   "frames per call": n_frames, "n": n, "ms/call": 1e3 * seconds, "frames/s": n_frames / seconds,
                   "samples/s": n_frames * n / seconds}
            if generator is not None:
                cyclegan_s = _cyclegan_seconds(generator, n_frames, grid, "cuda", 5)
                row["cyclegan ms/call"] = 1e3 * cyclegan_s
                row["time vs cyclegan"] = seconds / cyclegan_s
            row["goal"] = f"{goal:g} {unit}: {'met' if rate >= goal else 'missed'}"
            rows.append(row)
            print(row, file=sys.stderr)
    return rows


def diversity(real: str | None = None, skips_options: tuple[int, ...] = (0, 2, 3), epochs: int = 3,
              max_frames: int = 120) -> list[dict]:
    """Sample diversity with and without skip connections: small models (64 × 64, widths 8-16-32-64) trained
    `epochs` epochs (cycle 1 only) on the first `max_frames` real frames, then 8 samples of each validation
    frame at temperature 1. Reports the mean per-pixel std across samples and its ratio to the pixel std
    of the validation images themselves (1 = samples as different as different frames)."""
    real = str(real_oculus_dir()) if real is None else real
    from sonar_realism.models.datasets import load_grid_frames
    from sonar_realism.models.train import TrainConfig, fit

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for skips in skips_options:
            model = CDFCVAEConfig(grid=(64, 64), widths=(8, 16, 32, 64), skips=skips, upsample="resize_conv")
            cfg = TrainConfig(model=model, epochs1=epochs, epochs2=0, max_frames=max_frames, batch_size=16)
            run_dir = Path(tmp) / f"skips{skips}"
            fit(cfg, real, None, run_dir, device="cpu", progress=False)
            translator = Translator.from_checkpoint(run_dir / "model.safetensors", device="cpu")
            val = load_grid_frames(real, (64, 64), max_frames=max_frames)
            frames = [SonarImage(image, uniform_ranges(64, 30.0), uniform_azimuths(64, np.radians(130)))
                      for image in val.images[-16:]]
            samples = np.stack([f.intensity for f in translator.translate(frames, 8, 1.0, seed=0)])
            per_pixel_std = float(samples.std(axis=1).mean())
            data_std = float(np.stack([f.intensity for f in frames]).std())
            rows.append({"skips": skips, "epochs": epochs, "per-pixel std across 8 samples": per_pixel_std,
                         "ratio to image std": per_pixel_std / data_std,
                         "posterior sigma (mean)": float(np.exp(0.5 * translator.model.encoder_sim(
                             torch.from_numpy(val.images[-16:, None]))[1].detach()).mean())})
            print(rows[-1], file=sys.stderr)
    return rows


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import markdown

    device = sys.argv[sys.argv.index("--device") + 1] if "--device" in sys.argv else None
    print(markdown(diversity() if "--diversity" in sys.argv else run((device,) if device else None)))
