"""`sonar-realism inspect PATH [--json]`: what a recording holds, frame by frame, and what the reader skipped."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sonar_realism.arguments import positive_int
from sonar_realism.frames import SonarImage
from sonar_realism.io import read_frames, sniff
from sonar_realism.io.report import ReadReport


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="a recording: frames folder, image folder, .oculus log, raw stream, NPZ, "
                                     "PNG/TIFF, ROS 1 bag, ROS 2 bag folder, MCAP")
    parser.add_argument("--topic", help="ROS bags: the sonar topic (default: the one found by message type)")
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of a table")
    parser.add_argument("--max-frames", type=positive_int, default=None, metavar="N",
                        help="stop after N frames (default: read the whole recording)")
    parser.add_argument("--quiet", action="store_true", help="summary only, no per-frame lines")


def describe(frame: SonarImage, index: int) -> dict[str, Any]:
    """The metadata of one frame as plain JSON-able values."""
    return {
        "index": index,
        "seq": frame.seq,
        "stamp_ns": frame.stamp_ns,
        "shape": list(frame.intensity.shape),
        "dtype": frame.intensity.dtype.name,
        "n_samples": frame.n_samples,
        "n_ranges": frame.n_ranges,
        "n_beams": frame.n_beams,
        "min_range_m": float(frame.ranges_m[0]),
        "max_range_m": frame.max_range_m,
        "range_resolution_m": frame.range_resolution_m,
        "bearing_min_deg": math.degrees(float(frame.azimuths_rad[0])),
        "bearing_max_deg": math.degrees(float(frame.azimuths_rad[-1])),
        "frame_id": frame.frame_id,
        "intensity_scale": frame.intensity_scale,
        "meta": frame.meta,
    }


def summarise(frames: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts and spans over the per-frame descriptions."""
    if not frames:
        return {"frames": 0}
    stamps = [f["stamp_ns"] for f in frames if f["stamp_ns"]]
    summary: dict[str, Any] = {
        "frames": len(frames),
        "shapes": dict(Counter("x".join(map(str, f["shape"])) for f in frames)),
        "dtypes": dict(Counter(f["dtype"] for f in frames)),
        "max_range_m": [min(f["max_range_m"] for f in frames), max(f["max_range_m"] for f in frames)],
        "bearing_span_deg": [min(f["bearing_min_deg"] for f in frames), max(f["bearing_max_deg"] for f in frames)],
        "seq": [frames[0]["seq"], frames[-1]["seq"]],
        "geometry_assumed": sum(bool(f["meta"].get("geometry_assumed")) for f in frames),
    }
    if stamps:
        summary["first_stamp"] = _iso(min(stamps))
        summary["last_stamp"] = _iso(max(stamps))
        summary["duration_s"] = (max(stamps) - min(stamps)) / 1e9
        if len(stamps) > 1 and summary["duration_s"] > 0:
            summary["rate_hz"] = (len(stamps) - 1) / summary["duration_s"]
    return summary


def run(args: argparse.Namespace) -> int:
    report = ReadReport(source=args.path)
    kind = sniff(args.path) if Path(args.path).exists() else None
    frames: list[dict[str, Any]] = []
    for index, frame in enumerate(read_frames(args.path, report, topic=args.topic)):
        if args.max_frames is not None and index >= args.max_frames:
            break
        frames.append(describe(frame, index))
        if not args.json and not args.quiet:
            _print_frame_line(frames[-1])
    summary = summarise(frames)
    if args.json:
        document = {"path": args.path, "kind": kind, "summary": summary, "report": report.as_dict()}
        if not args.quiet:
            document["frames"] = frames
        json.dump(document, sys.stdout, indent=1, default=str)
        sys.stdout.write("\n")
    else:
        _print_summary(args.path, kind, summary, report)
    return 0


def _iso(stamp_ns: int) -> str:
    return datetime.fromtimestamp(stamp_ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")


def _print_frame_line(f: dict[str, Any]) -> None:
    stamp = _iso(f["stamp_ns"]) if f["stamp_ns"] else "-"
    assumed = "  (geometry assumed)" if f["meta"].get("geometry_assumed") else ""
    print(f"{f['index']:6d}  seq {f['seq']:<8d} {stamp:<30s} {'x'.join(map(str, f['shape'])):>14s} {f['dtype']:<8s}"
          f" range {f['min_range_m']:.2f}-{f['max_range_m']:.2f} m  bearings {f['bearing_min_deg']:+.1f}.."
          f"{f['bearing_max_deg']:+.1f}°{assumed}")


def _print_summary(path: str, kind: str | None, summary: dict[str, Any], report: ReadReport) -> None:
    print(f"\n{path}: {kind or 'unknown'}, {summary['frames']} frame(s)")
    for key, value in summary.items():
        if key != "frames":
            print(f"  {key}: {value}")
    if report.skipped:
        print("  skipped: " + ", ".join(f"{reason} ×{count}" for reason, count in sorted(report.skipped.items())))
    for problem in report.problems:
        print(f"  problem: {problem}")
