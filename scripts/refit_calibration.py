"""Refit one part of a CALIB.json on its own recording, as `calibrate` fits it, keeping every other value.

For a calibration made before `calibrate` fitted that part (a full `calibrate` run would refit everything):

    python scripts/refit_calibration.py targets --calibration sonar_realism/assets/oculus_calibration.json \\
        --real ../shared/data/real/oculus_polar_seabed/dataset --match Oculus_20250805_173650 \\
        [--targets-from ../shared/data/real/oculus_polar_seabed/dataset] --out CALIB.json
    python scripts/refit_calibration.py texture --calibration ... --real ... [--near-field] --out CALIB.json
    python scripts/refit_calibration.py export-knee --calibration ... --real ... --out CALIB.json

- `targets`: the targets measured on the recording (its annotations with `--targets-from`, as `calibrate
  --targets-from`; else the shadow detector) and matched under the calibration's own effects
  (`calibrate.match_targets`: the shadows' floor, then the share of frames or the return).
- `texture`: the learned texture trained on the calibrated simulator's local mean levels against the recording
  (`calibrate.with_learned_texture`); under it the noise floor (`match_noise_floor`) and the export knee
  (`match_export_knee`) are matched again; last the generator is trained afresh on the levels of that floor, the
  ones it is drawn on. With `--near-field` the ring-down is first matched to the recording's near-field band
  (`calibrate.match_near_field`, as `calibrate` does before the floor).
- `export-knee`: the export knee (models/speckle.compress_top) around the recording's local means
  (`texture.with_export_knee`), then on the calibrated sim's frames under the final gain (`match_export_knee`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.io import load_recording  # noqa: E402
from sonar_realism.models.speckle_fit import top_ratio  # noqa: E402
from sonar_realism.sim.annotations import parse_classes, read_annotations  # noqa: E402
from sonar_realism.sim.calibrate import (  # noqa: E402
    CalibrateConfig,
    effect_in,
    match_export_knee,
    match_near_field,
    match_noise_floor,
    match_targets,
    near_field_profile,
    prepare_frames,
    target_terms_from_annotations,
    target_terms_from_shadows,
    with_learned_texture,
)
from sonar_realism.sim.calibration import Calibration, load_calibration, save_calibration  # noqa: E402
from sonar_realism.sim.effects import TvgNoise  # noqa: E402
from sonar_realism.sim.fingerprint import fingerprint, per_frame_rescaled  # noqa: E402
from sonar_realism.sim.texture import with_export_knee  # noqa: E402


def recording_images(args: argparse.Namespace) -> list[np.ndarray]:
    """The recording's frames as the export scaled them (to their maximum)."""
    return [per_frame_rescaled(f.intensity) for f in load_recording(args.real, args.match, args.limit)]


def refit_targets(calibration: Calibration, args: argparse.Namespace) -> tuple[Calibration, str]:
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
    return calibration, f"targets: {calibration.targets}"


def refit_texture(calibration: Calibration, args: argparse.Namespace) -> tuple[Calibration, str]:
    if calibration.texture is None:
        raise SystemExit(f"{args.calibration}: no fitted texture (calibrate --texture none), so no learned one")
    images = recording_images(args)
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
    assert calibration.learned_texture is not None and calibration.texture is not None
    return calibration, (f"learned texture: {calibration.learned_texture.steps} steps, critic loss "
                         f"{calibration.learned_texture.critic_loss}; tvg_noise.noise_amplitude "
                         f"{effect_in(chain, TvgNoise).noise_amplitude:.4f}, "
                         f"export knee {calibration.texture.export_knee}")


def refit_export_knee(calibration: Calibration, args: argparse.Namespace) -> tuple[Calibration, str]:
    if calibration.texture is None:
        raise SystemExit(f"{args.calibration}: no fitted texture, so no export knee to fit")
    images = recording_images(args)
    calibration = dataclasses.replace(calibration, texture=with_export_knee(calibration.texture, images))
    assert calibration.texture is not None
    around_means = calibration.texture.export_knee
    calibration = match_export_knee(calibration, calibration.effect_chain(), fingerprint(images),
                                    float(np.median([top_ratio(i) for i in images])),
                                    CalibrateConfig.mounting_frames, args.seed)
    assert calibration.texture is not None
    return calibration, (f"export knee {around_means} around the recording's means, "
                         f"{calibration.texture.export_knee} on the calibrated sim")


def main(argv: list[str] | None = None) -> int:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--calibration", required=True, help="the CALIB.json to refit (or a shipped name)")
    common.add_argument("--real", required=True, help="the recording it was calibrated on")
    common.add_argument("--match", help="only files whose path contains this (as `calibrate --match`)")
    common.add_argument("--limit", type=int, help="at most this many frames (as `calibrate --limit`)")
    common.add_argument("--seed", type=int, default=CalibrateConfig.seed)
    common.add_argument("--out", required=True)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parts = parser.add_subparsers(dest="part", required=True)
    targets = parts.add_parser("targets", parents=[common], help="the targets (annotations or shadows)")
    targets.add_argument("--targets-from", action="append", metavar="FOLDER",
                         help="the recording's annotations (as `calibrate --targets-from`); else its shadows")
    targets.add_argument("--target-classes", help="only these class ids of the annotations (as `calibrate`)")
    targets.set_defaults(refit=refit_targets)
    texture = parts.add_parser("texture", parents=[common], help="the learned texture, noise floor, export knee")
    texture.add_argument("--steps", type=int, default=CalibrateConfig.learned_steps, help="training steps")
    texture.add_argument("--near-field", action="store_true",
                         help="match the ring-down to the recording's near-field band first (calibrate's step)")
    texture.set_defaults(refit=refit_texture)
    parts.add_parser("export-knee", parents=[common], help="the export knee").set_defaults(refit=refit_export_knee)
    args = parser.parse_args(argv)
    calibration, summary = args.refit(load_calibration(args.calibration), args)
    calibration.validate()
    save_calibration(calibration, args.out)
    print(f"{summary}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
