"""Fit the export knee (models/speckle.compress_top) into a CALIB.json made before `calibrate` fitted it.

What `calibrate` does for it, on the calibration's own recording: the knee around the recording's local means
(`texture.with_export_knee`, as the texture fit), then on the calibrated sim's frames under the final gain
(`calibrate.match_export_knee`). Every other value stays as it is (a full `calibrate` run would refit them all):

    python scripts/refit_export_knee.py --calibration sonar_realism/assets/oculus_calibration.json \\
        --real ../shared/data/real/oculus_polar_seabed/dataset --match Oculus_20250805_173650 --out CALIB.json
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.models.speckle_fit import top_ratio  # noqa: E402
from sonar_realism.sim.calibrate import CalibrateConfig, load_recording, match_export_knee  # noqa: E402
from sonar_realism.sim.calibration import load_calibration, save_calibration  # noqa: E402
from sonar_realism.sim.fingerprint import fingerprint, per_frame_rescaled  # noqa: E402
from sonar_realism.sim.texture import with_export_knee  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibration", required=True, help="a CALIB.json with a fitted texture")
    parser.add_argument("--real", required=True, help="the recording it was calibrated on")
    parser.add_argument("--match", help="only files whose path contains this (as `calibrate --match`)")
    parser.add_argument("--limit", type=int, help="at most this many frames (as `calibrate --limit`)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    calibration = load_calibration(args.calibration)
    if calibration.texture is None:
        raise SystemExit(f"{args.calibration}: no fitted texture, so no export knee to fit")
    images = [per_frame_rescaled(f.intensity) for f in load_recording(args.real, args.match, args.limit)]
    calibration = dataclasses.replace(calibration, texture=with_export_knee(calibration.texture, images))
    around_means = calibration.texture.export_knee
    config = CalibrateConfig()
    calibration = match_export_knee(calibration, calibration.effect_chain(), fingerprint(images),
                                     float(np.median([top_ratio(i) for i in images])), config.mounting_frames,
                                     config.seed)
    save_calibration(calibration, args.out)
    print(f"export knee {around_means} around the recording's means, {calibration.texture.export_knee} on the "
          f"calibrated sim; wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
