"""`sonar-realism simulate`: write simulated frames, per-frame object masks and a manifest to a folder.

    sonar-realism simulate --effects none|all|speckle,tvg_noise,... --n N --out DIR [--scene NAME] [--seed S]
                           [--param effect.name=value ...] [--beams B] [--ranges R] [--range-m M]
    sonar-realism simulate --calibration CALIB.json --n N --seed S --out DIR [--scene NAME] [--param ...]

With --calibration every frame is a new view of the calibrated sensor in its setting (grid, mounting, seabed,
targets, effects, residual gain: sim/calibrated.py); --effects picks from the calibrated chain (default: all of
it), --param overrides its parameters, and --scene renders that named scene on the calibrated sensor instead.

DIR gets a frames folder (read back by `sonar_realism.io.read_frames`), `masks/NNNNNN.png` (uint8 object id per
[range, beam] pixel, 0 = no object) and `manifest.json` (scene, seed, sensor, poses, objects, effects with
their parameters, the command line).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np
from tqdm import tqdm

from sonar_realism.arguments import non_negative_int, output_folder, positive_int
from sonar_realism.config import to_dict
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.io import write_frames
from sonar_realism.sim.calibrated import calibrated_chain, finish, sensor_for, simulate_calibrated
from sonar_realism.sim.calibration import SHIPPED_CALIBRATIONS, load_calibration
from sonar_realism.sim.effects import PIPELINE_ORDER, resolve_effects
from sonar_realism.sim.masks import MASK_FILES, clear_masks, write_mask
from sonar_realism.sim.scene import SCENES, build_scene
from sonar_realism.sim.sensor import SENSORS, SensorConfig
from sonar_realism.sim.simulate import simulate

STORAGE_DTYPES = ("float32", "uint16")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calibration", help="CALIB.json from `sonar-realism calibrate`, or a shipped one by name "
                                              f"({', '.join(sorted(SHIPPED_CALIBRATIONS))}): frames of that sensor")
    parser.add_argument("--scene", help=f"scene name ({', '.join(SCENES)}); default: default, or with --calibration a "
                                        "new randomised view per frame")
    parser.add_argument("--effects", help=f"none, all, or a comma list of: {', '.join(PIPELINE_ORDER)} (default: none; "
                                          "with --calibration all, calibrated)")
    parser.add_argument("--n", type=int, default=24, help="number of frames (default 24)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="seed of the world and the per-ping draws (default 0)")
    parser.add_argument("--param", action="append", default=[], metavar="EFFECT.NAME=VALUE",
                        help="override an effect parameter, e.g. speckle.shape_nu=3 (repeatable)")
    parser.add_argument("--sensor", default="m1200d_1200khz", choices=sorted(SENSORS),
                        help="sensor preset (default m1200d_1200khz: 1.2 MHz, 130 x 20 deg)")
    parser.add_argument("--beams", type=int, help="number of beams (default from the sensor: 256)")
    parser.add_argument("--ranges", type=int, help="number of range bins (default from the sensor: 512)")
    parser.add_argument("--range-m", type=float, dest="range_m", help="maximum range in metres (default 15)")
    parser.add_argument("--dtype", default="float32", choices=STORAGE_DTYPES,
                        help="storage of frames without gamma_quantization: float32 amplitude, or uint16 "
                             "(amplitude * 65535, compact lossless PNG); 8-bit output comes from gamma_quantization")
    parser.add_argument("--workers", type=positive_int, default=1,
                        help="render frames on this many processes (same frames, same order; default 1)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def parse_params(items: list[str]) -> dict[str, dict[str, Any]]:
    """["speckle.shape_nu=3", ...] -> {"speckle": {"shape_nu": 3}}."""
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        effect, dot, name = key.strip().partition(".")
        if not sep or not dot or not effect or not name:
            raise ConfigError(f"--param {item!r}: expected EFFECT.NAME=VALUE, e.g. speckle.shape_nu=3")
        try:
            value: Any = int(text) if text.strip().lstrip("+-").isdigit() else float(text)
        except ValueError as exc:
            raise ConfigError(f"--param {item!r}: {text!r} is not a number") from exc
        out.setdefault(effect, {})[name] = value
    return out


def sensor_from_args(args: argparse.Namespace) -> SensorConfig:
    changes = {k: v for k, v in (("n_beams", args.beams), ("n_ranges", args.ranges), ("max_range_m", args.range_m))
               if v is not None}
    sensor = dataclasses.replace(SENSORS[args.sensor], **changes)
    sensor.validate()
    return sensor


def run(args: argparse.Namespace) -> int:
    if args.calibration:
        return run_calibrated(args)
    args.scene = args.scene or "default"
    args.effects = args.effects or "none"
    if args.scene not in SCENES:
        raise ConfigError(f"unknown scene {args.scene!r}; known scenes: {', '.join(SCENES)}")
    if args.n < 1:
        raise ConfigError(f"--n: expected at least 1 frame, got {args.n}")
    sensor = sensor_from_args(args)
    params = parse_params(args.param)
    effects = resolve_effects(args.effects, params)  # validates names and parameters before any work
    out = output_folder(args.out, "--out")
    clear_masks(out)

    world = build_scene(args.scene, args.seed, sensor.max_range_m)
    poses = world.trajectory(args.n)
    simulated = tqdm(simulate(world, effects, args.n, args.seed, sensor, workers=args.workers), desc="simulate",
                     total=args.n, unit="frame", disable=args.quiet)

    def frames() -> Iterator[SonarImage]:
        for index, (frame, mask) in enumerate(simulated):
            write_mask(out, index, mask)
            yield _stored(frame, args.dtype)

    count = write_frames(frames(), out)
    simulated.close()
    manifest = {
        "scene": args.scene, "seed": args.seed, "n": count, "trajectory": world.trajectory_kind,
        "sensor": to_dict(sensor), "effects": [{"name": e.name, "params": e.params()} for e in effects],
        "poses": [p.as_dict() for p in poses],
        "objects": [{"id": o.object_id, "kind": o.kind, "position": list(o.position), "material": o.material}
                    for o in world.objects],
        "masks": f"{MASK_FILES}, ids as in 'objects'",
        "storage": args.dtype if not any(e.name == "gamma_quantization" for e in effects) else "uint8",
        "command": "sonar-realism simulate " + " ".join(shlex.quote(a) for a in _argv_of(args)),
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {count} frames, masks and manifest.json to {out}", file=sys.stderr)
    return 0


def run_calibrated(args: argparse.Namespace) -> int:
    """Frames of the calibrated sensor: each a new randomised view, or `--scene` on the calibrated sensor."""
    calibration = load_calibration(args.calibration)
    if args.n < 1:
        raise ConfigError(f"--n: expected at least 1 frame, got {args.n}")
    if args.scene is not None and args.scene not in SCENES:
        raise ConfigError(f"unknown scene {args.scene!r}; known scenes: {', '.join(SCENES)}")
    params = parse_params(args.param)
    chain = calibrated_chain(calibration, args.effects or "all", params)
    out = output_folder(args.out, "--out")
    clear_masks(out)
    objects: list[list[dict[str, Any]]] = []
    poses: list[dict[str, float]] = []

    if args.scene is None:
        pairs = simulate_calibrated(calibration, args.n, args.seed, chain, workers=args.workers)
    else:
        sensor = sensor_for(calibration.grid.modes[0], calibration.mounting.vertical_fov_deg)
        world = build_scene(args.scene, args.seed, sensor.max_range_m)
        pairs = ((finish(calibration, frame, chain, np.random.default_rng([args.seed, i])), mask)
                 for i, (frame, mask) in enumerate(simulate(world, "none", args.n, args.seed, sensor,
                                                            workers=args.workers)))

    def frames() -> Iterator[SonarImage]:
        for index, (frame, mask) in enumerate(tqdm(pairs, desc="simulate", total=args.n, unit="frame",
                                                   disable=args.quiet)):
            write_mask(out, index, mask)
            objects.append(list(frame.meta.get("objects", [])))
            poses.append(dict(frame.meta.get("pose", {})))
            yield _stored(frame, args.dtype)

    count = write_frames(frames(), out)
    argv = ["--calibration", str(args.calibration), "--n", str(args.n), "--seed", str(args.seed), "--out",
            str(args.out)] + (["--scene", args.scene] if args.scene else []) + (
        ["--effects", args.effects] if args.effects else []) + [x for item in args.param for x in ("--param", item)]
    manifest = {
        "calibration": str(args.calibration), "calibration_source": calibration.source,
        "scene": args.scene or "calibrated (a new view per frame)", "seed": args.seed, "n": count,
        "effects": [{"name": e.name, "params": e.params()} for e in chain], "poses": poses,
        "objects": objects if args.scene is None else [
            {"id": o.object_id, "kind": o.kind, "position": list(o.position), "material": o.material}
            for o in world.objects],
        "masks": f"{MASK_FILES}; with a calibration the ids "
                 "are per frame (objects[i] lists frame i's)",
        "command": "sonar-realism simulate " + " ".join(shlex.quote(a) for a in argv),
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {count} calibrated frames, masks and manifest.json to {out}", file=sys.stderr)
    return 0


def _stored(frame: SonarImage, dtype: str) -> SonarImage:
    if dtype == "uint16" and frame.intensity.dtype == np.float32:
        counts = np.rint(np.clip(frame.intensity, 0.0, 1.0) * 65535.0).astype(np.uint16)
        return frame.replace(intensity=counts, intensity_scale=65535.0)
    return frame


def _argv_of(args: argparse.Namespace) -> list[str]:
    argv = ["--scene", args.scene, "--effects", args.effects, "--n", str(args.n), "--seed", str(args.seed),
            "--out", str(args.out), "--sensor", args.sensor, "--dtype", args.dtype]
    for flag, value in (("--beams", args.beams), ("--ranges", args.ranges), ("--range-m", args.range_m)):
        if value is not None:
            argv += [flag, str(value)]
    for item in args.param:
        argv += ["--param", item]
    return argv
