"""Run every benchmark and print one Markdown table per benchmark: `python bench/run.py [name ...]`.

Each `bench/bench_<name>.py` exposes `run() -> list[dict]`; rows carry their own baseline and ratio
columns, measured in the same run. Results also go to `bench/results.json` for docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ["oculus", "wire", "geometry", "sim", "model", "pipeline", "hop", "diagnose", "diagnose_heldout", "soak"]
ON_REQUEST = {"soak", "diagnose_heldout", "hop"}  # minutes long, or a diagnosis (hop): run by name only


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", HERE / f"bench_{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def markdown(rows: list[dict]) -> str:
    if not rows:
        return "(no rows)"
    columns = list(dict.fromkeys(key for row in rows for key in row))
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = [f"{row[c]:.4g}" if isinstance(row.get(c), float) else str(row.get(c, "")) for c in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def available() -> list[str]:
    found = sorted(p.stem.removeprefix("bench_") for p in HERE.glob("bench_*.py"))
    return [n for n in ORDER if n in found] + [n for n in found if n not in ORDER]


def parse_names(argv: list[str]) -> list[str]:
    names = available()
    parser = argparse.ArgumentParser(prog="python bench/run.py", description=__doc__.split("\n\n")[0],
                                     epilog=f"benchmarks: {', '.join(names)}")
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help="benchmarks to run (default: every one except soak, which takes minutes)")
    chosen = parser.parse_args(argv).names
    unknown = [n for n in chosen if n not in names]
    if unknown:
        parser.error(f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(names)}")
    return chosen or [n for n in names if n not in ON_REQUEST]


def main(argv: list[str]) -> int:
    names = parse_names(argv)
    results = {"machine": f"{cpu_model()}, {os.cpu_count()} cores", "date": time.strftime("%Y-%m-%d"),
               "python": platform.python_version(), "benchmarks": {}}
    print(f"machine: {results['machine']}  date: {results['date']}\n")
    for name in names:
        start = time.perf_counter()
        rows = load(name).run()
        results["benchmarks"][name] = rows
        print(f"## {name} ({time.perf_counter() - start:.0f} s)\n\n{markdown(rows)}\n", flush=True)
    (HERE / "results.json").write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
