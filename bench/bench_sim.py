"""Simulator throughput: frames/s at 256 x 512 and 512 x 1024 (beams x ranges), clean and with all effects.

    python bench/bench_sim.py [--frames N]

Rows per grid: a float32 copy of one frame (memory-bandwidth floor), the clean render (the reference of the
ratio column), every effect alone on a clean frame, all effects on a clean frame, and the whole simulator
(render + all effects), first in this process one frame at a time after one warm-up frame, then as
`simulate(..., workers=W)` runs it: a pool of W forked processes over frames (W = the machine's cores), timed
over the whole batch including the pool's start-up (its CPU column adds the workers' CPU to the parent's). Last,
the calibrated simulator on the shipped Oculus calibration (its own grids, 256 beams x 370-617 ranges), one
process. Issue 11's goal: render + all effects at 256 x 512 >= 60 frames/s on the 2-core machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import resource
import time
from collections.abc import Callable

import numpy as np

from sonar_realism.sim.calibrated import simulate_calibrated
from sonar_realism.sim.calibration import SHIPPED_CALIBRATIONS, load_calibration
from sonar_realism.sim.effects import PIPELINE_ORDER, apply_effects, make_effect
from sonar_realism.sim.scene import build_scene
from sonar_realism.sim.sensor import M1200D_1200KHZ
from sonar_realism.sim.simulate import frame_for, simulate

GRIDS = ((256, 512), (512, 1024))


def _rate(step: Callable[[int], object], frames: int) -> tuple[float, float]:
    """(frames per wall second, frames per CPU second of this process).

    On a shared machine the wall rate includes waiting for a core; the CPU rate is what the code costs.
    """
    step(0)  # warm-up: caches, lazy imports
    wall, cpu = time.perf_counter(), time.process_time()
    for i in range(frames):
        step(i + 1)
    return frames / (time.perf_counter() - wall), frames / max(time.process_time() - cpu, 1e-9)


def _cases(beams: int, ranges: int, frames: int) -> list[tuple[str, Callable[[int], object]]]:
    sensor = dataclasses.replace(M1200D_1200KHZ, n_beams=beams, n_ranges=ranges)
    scene = build_scene("default", 0, sensor.max_range_m)
    poses = scene.trajectory(frames + 1)
    clean = [frame_for(scene, poses[i], sensor, i)[0] for i in range(2)]
    all_effects = [make_effect(name) for name in PIPELINE_ORDER]

    def effects_on_clean(effects: list) -> Callable[[int], object]:
        return lambda i: apply_effects(clean[i % 2], effects, np.random.default_rng(i))

    cases: list[tuple[str, Callable[[int], object]]] = [
        ("float32 copy (floor)", lambda i: clean[i % 2].intensity.copy()),
        ("clean render (reference)", lambda i: frame_for(scene, poses[i], sensor, i)),
    ]
    cases += [(f"effect {name}", effects_on_clean([make_effect(name)])) for name in PIPELINE_ORDER]
    cases += [
        ("all effects on a clean frame", effects_on_clean(all_effects)),
        ("render + all effects", lambda i: apply_effects(frame_for(scene, poses[i], sensor, i)[0], all_effects,
                                                         np.random.default_rng(i))),
    ]
    return cases


def _cpu_seconds() -> float:
    """CPU of this process and of its finished children (a pool's workers once it has joined them)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def _pool_rate(beams: int, ranges: int, frames: int, workers: int) -> tuple[float, float]:
    """(frames per wall second, frames per CPU second of the parent and its workers) of simulate() on a pool."""
    sensor = dataclasses.replace(M1200D_1200KHZ, n_beams=beams, n_ranges=ranges)
    scene = build_scene("default", 0, sensor.max_range_m)
    wall, cpu = time.perf_counter(), _cpu_seconds()
    count = sum(1 for _ in simulate(scene, "all", frames, 0, sensor, workers=workers))
    return count / (time.perf_counter() - wall), count / max(_cpu_seconds() - cpu, 1e-9)


def _calibrated_rate(frames: int) -> tuple[float, float]:
    """(frames per wall second, per CPU second) of the calibrated simulator on the shipped Oculus calibration."""
    calibration = load_calibration(SHIPPED_CALIBRATIONS["oculus"])
    next(simulate_calibrated(calibration, 1, 1))  # warm-up
    wall, cpu = time.perf_counter(), time.process_time()
    count = sum(1 for _ in simulate_calibrated(calibration, frames, 0))
    return count / (time.perf_counter() - wall), count / max(time.process_time() - cpu, 1e-9)


def run(frames: int = 20) -> list[dict]:
    rows: list[dict] = []
    workers = os.cpu_count() or 1
    for beams, ranges in GRIDS:
        grid = f"{beams} x {ranges}"
        measured = [(label, *_rate(step, frames)) for label, step in _cases(beams, ranges, frames)]
        measured.append((f"render + all effects, {workers} processes", *_pool_rate(beams, ranges, 4 * frames,
                                                                                     workers)))
        if (beams, ranges) == GRIDS[0]:
            measured.append(("calibrated simulator (Oculus calibration, 256 x 370-617), 1 process",
                             *_calibrated_rate(max(2, frames // 4))))
        reference = next(rate for label, rate, _ in measured if label.startswith("clean render"))
        rows += [{"grid": grid, "case": label, "frames_per_s": rate, "ms_per_frame": 1000.0 / rate,
                  "cpu_ms_per_frame": 1000.0 / cpu_rate, "vs_clean_render": rate / reference}
                 for label, rate, cpu_rate in measured]
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| grid (beams x ranges) | case | frames/s (wall) | ms/frame (wall) | CPU ms/frame | "
             "speed vs clean render |", "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['grid']} | {r['case']} | {r['frames_per_s']:.1f} | {r['ms_per_frame']:.2f} | "
                     f"{r['cpu_ms_per_frame']:.2f} | {r['vs_clean_render']:.2f}x |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="timed frames per case (default 20)")
    args = parser.parse_args()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, load average {load:.1f}, "
          f"python {platform.python_version()}, numpy {np.__version__}")
    print(markdown(run(args.frames)))


if __name__ == "__main__":
    main()
