"""`sonar-realism diagnose --sim DIR --real DIR --out DIR`: where the sim-to-real gap lies, which effect causes it,
and how far it shrinks. Writes DIR/diagnosis.json, DIR/report.html (self-contained), DIR/report.md and the
figures."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Sequence

import numpy as np
from tqdm import tqdm

from sonar_realism.arguments import json_object, non_negative_int, output_folder
from sonar_realism.config import from_dict, parse_grid
from sonar_realism.diagnose.config import DiagnoseConfig
from sonar_realism.diagnose.diagnosis import diagnose
from sonar_realism.diagnose.report import write_report
from sonar_realism.diagnose.scene_terms import SceneStart
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import resample_to_grid
from sonar_realism.io import load_recording
from sonar_realism.sim.calibration import load_calibration


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sim", required=True, nargs="+", help="simulated frames (folder or recording; several ok)")
    parser.add_argument("--real", required=True, nargs="+", help="real frames (folder or recording; several ok)")
    parser.add_argument("--out", required=True, help="output folder: diagnosis.json, report.html, report.md, figures")
    parser.add_argument("--resample", action="store_true",
                        help="put frames of other grids on the real set's most common grid instead of refusing")
    parser.add_argument("--grid", help="resample both sets onto RANGESxBEAMS (e.g. 128x128, a model's grid)")
    parser.add_argument("--normalize", choices=("none", "max"), default="none",
                        help="'max' divides every frame by its maximum (for real sets exported that way)")
    parser.add_argument("--effects", default="", help="candidate effects, comma separated (default: the catalogue)")
    parser.add_argument("--max-frames", type=int, default=500, help="use at most this many frames per set")
    parser.add_argument("--calibration", help="CALIB.json of the real sensor (or a shipped name: oculus): the sim's "
                                              "geometry and scene (mounting, seabed patchiness) become candidates "
                                              "beside the sensor effects, starting where the calibration puts them")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--config", help="JSON file with DiagnoseConfig fields (overrides the options above)")


def run(args: argparse.Namespace) -> int:
    if args.max_frames < 4:
        raise ConfigError(f"--max-frames: need at least 4 frames per set, got {args.max_frames}")
    settings = {"normalize": args.normalize, "seed": args.seed,
                "effects": [e.strip() for e in args.effects.split(",") if e.strip()]}
    if args.config:
        settings.update(json_object(args.config, "--config", "DiagnoseConfig fields"))
    config = from_dict(DiagnoseConfig, settings, where="diagnose config")
    output_folder(args.out, "--out")
    scene = SceneStart.from_calibration(load_calibration(args.calibration)) if args.calibration else None
    sim = load_set(args.sim, args.max_frames)
    real = load_set(args.real, args.max_frames)
    if args.grid or args.resample:
        most_common = Counter(f.intensity.shape[-2:] for f in real).most_common(1)[0][0]
        grid = parse_grid(args.grid) if args.grid else most_common
        sim, real = on_grid(sim, grid), on_grid(real, grid)
    with tqdm(desc="diagnose", unit="fit step") as bar:
        def progress(message: str) -> None:
            bar.update()
            bar.write(message, file=sys.stderr)

        diagnosis = diagnose(sim, real, config, progress=progress, scene=scene)
    report = write_report(diagnosis, args.out)
    d = diagnosis
    ambiguous = "".join(f"; ambiguous: {' or '.join(a.effect for a in group.effects)}" for group in d.ambiguous)
    print(f"gap before {d.gap_before:.4g} -> after {', '.join(d.selected) or 'nothing'}: "
          f"{d.gap_after_selected:.4g} ({100 * d.gap_closed:.0f}% closed; {d.verdict}{ambiguous}); report: {report}")
    return 0


def load_set(paths: Sequence[str], max_frames: int) -> list[SonarImage]:
    """All frames of `paths`, evenly thinned to at most `max_frames`."""
    frames: list[SonarImage] = []
    for path in paths:
        frames.extend(load_recording(path))
    if not frames:
        raise ConfigError(f"no frames found in {', '.join(paths)} (nor in their subfolders)")
    if len(frames) > max_frames:
        keep = np.linspace(0, len(frames) - 1, max_frames).round().astype(int)
        frames = [frames[i] for i in keep]
    return frames


def on_grid(frames: Sequence[SonarImage], grid: tuple[int, int]) -> list[SonarImage]:
    """Frames of another shape resampled onto `grid` (ranges x beams) over their own range and bearing span."""
    return [f if f.intensity.shape[-2:] == grid else resample_to_grid(f, *grid) for f in frames]
