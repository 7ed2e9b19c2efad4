"""Train the learned texture of a CALIB.json on its own simulated levels, as `calibrate --texture learned` does.

For a calibration made before the texture generator was fitted unpaired (or without one), as `calibrate` does
it: the generator is trained on the calibrated simulator's local mean levels against the recording
(`calibrate.with_learned_texture`); under it, the noise floor (the recording's share of black pixels,
`match_noise_floor`) and the export knee (`match_export_knee`) are matched again; last the generator is trained
afresh on the levels of that floor, the ones it is drawn on. With `--near-field`, the ring-down is first matched to
the recording's near-field band (`calibrate.match_near_field`, as `calibrate` does before the floor). Every other
value stays as it is (a full `calibrate` run would refit them all):

    python scripts/refit_calibration_texture.py --calibration sonar_realism/assets/oculus_calibration.json \\
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
from sonar_realism.sim.calibrate import (  # noqa: E402
    CalibrateConfig,
    effect_in,
    load_recording,
    match_export_knee,
    match_near_field,
    match_noise_floor,
    near_field_profile,
    with_learned_texture,
)
from sonar_realism.sim.calibration import load_calibration, save_calibration  # noqa: E402
from sonar_realism.sim.effects import TvgNoise  # noqa: E402
from sonar_realism.sim.fingerprint import fingerprint, per_frame_rescaled  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibration", required=True, help="a CALIB.json with a fitted texture (or a shipped name)")
    parser.add_argument("--real", required=True, help="the recording it was calibrated on")
    parser.add_argument("--match", help="only files whose path contains this (as `calibrate --match`)")
    parser.add_argument("--limit", type=int, help="at most this many frames (as `calibrate --limit`)")
    parser.add_argument("--steps", type=int, default=CalibrateConfig.learned_steps, help="training steps")
    parser.add_argument("--seed", type=int, default=CalibrateConfig.seed)
    parser.add_argument("--near-field", action="store_true",
                        help="match the ring-down to the recording's near-field band first (calibrate's step)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    calibration = load_calibration(args.calibration)
    if calibration.texture is None:
        raise SystemExit(f"{args.calibration}: no fitted texture (calibrate --texture none), so no learned one")
    images = [per_frame_rescaled(f.intensity) for f in load_recording(args.real, args.match, args.limit)]
    config, target = CalibrateConfig(), fingerprint(images)
    if args.near_field:
        chain = match_near_field(calibration, calibration.effect_chain(), near_field_profile(images),
                                 config.mounting_frames, args.seed)
        calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
    calibration = with_learned_texture(calibration, images, args.steps, args.seed, config.learned_generators,
                                       progress=True)
    chain = match_noise_floor(calibration, calibration.effect_chain(), target.near_zero, config.mounting_frames,
                              args.seed)
    calibration = dataclasses.replace(calibration, effects={e.name: e.params() for e in chain})
    calibration = match_export_knee(calibration, chain, target, float(np.median([top_ratio(i) for i in images])),
                                    config.mounting_frames, args.seed)
    calibration = with_learned_texture(calibration, images, args.steps, args.seed, config.learned_generators,
                                       progress=True)
    calibration.validate()
    save_calibration(calibration, args.out)
    assert calibration.learned_texture is not None
    assert calibration.texture is not None
    print(f"learned texture: {calibration.learned_texture.steps} steps, critic loss "
          f"{calibration.learned_texture.critic_loss}; tvg_noise.noise_amplitude "
          f"{effect_in(chain, TvgNoise).noise_amplitude:.4f}, "
          f"export knee {calibration.texture.export_knee}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
