"""Measure a CALIB.json's targets again from its recording, as `calibrate` does, keeping every other value.

For a calibration made before targets' shadows were measured (their depth: `targets.shadow_level`) or before
targets could be larger than 0.3 of the range window: the targets are measured on the recording (its annotations
with `--targets-from`, as `calibrate --targets-from`; else the shadow detector) and matched under the
calibration's own effects (`calibrate.match_targets`: the shadows' floor, then the share of frames or the
return). A full `calibrate` run would refit everything else as well:

    python scripts/refit_calibration_targets.py --calibration sonar_realism/assets/oculus_calibration.json \\
        --real ../shared/data/real/oculus_polar_seabed/dataset --match Oculus_20250805_173650 \\
        --targets-from ../shared/data/real/oculus_polar_seabed/dataset --out CALIB.json
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.sim.annotations import parse_classes, read_annotations  # noqa: E402
from sonar_realism.sim.calibrate import (  # noqa: E402
    CalibrateConfig,
    load_recording,
    match_targets,
    prepare_frames,
    target_terms_from_annotations,
    target_terms_from_shadows,
)
from sonar_realism.sim.calibration import load_calibration, save_calibration  # noqa: E402
from sonar_realism.sim.fingerprint import per_frame_rescaled  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibration", required=True, help="the CALIB.json to refit (or a shipped name)")
    parser.add_argument("--real", required=True, help="the recording it was calibrated on")
    parser.add_argument("--match", help="only files whose path contains this (as `calibrate --match`)")
    parser.add_argument("--limit", type=int, help="at most this many frames (as `calibrate --limit`)")
    parser.add_argument("--targets-from", action="append", metavar="FOLDER",
                        help="the recording's annotations (as `calibrate --targets-from`); else its shadows")
    parser.add_argument("--target-classes", help="only these class ids of the annotations (as `calibrate`)")
    parser.add_argument("--seed", type=int, default=CalibrateConfig.seed)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    calibration = load_calibration(args.calibration)
    config = CalibrateConfig(vertical_fov_deg=calibration.mounting.vertical_fov_deg)
    recording = load_recording(args.real, args.match, args.limit)
    annotations = (read_annotations(recording, args.targets_from,
                                    parse_classes(args.target_classes) if args.target_classes else None)
                   if args.targets_from else None)
    frames, _ = prepare_frames(recording, config)
    images = [per_frame_rescaled(f.intensity) for f in frames]
    rng = np.random.default_rng(args.seed)
    measured = (target_terms_from_annotations(frames, images, annotations, rng, config.bootstrap)
                if annotations is not None else target_terms_from_shadows(frames, images, rng, config.bootstrap))
    calibration = match_targets(dataclasses.replace(calibration, targets=measured), calibration.effect_chain(),
                                annotations is not None, config, args.seed)
    calibration.validate()
    save_calibration(calibration, args.out)
    print(f"targets: {calibration.targets}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
