"""Held-out validation of the gap diagnosis (issue 13): effects it has never seen the code of.

"Real" frames are clean simulator frames (`--effects none`: the plain simulator on named scenes, and the
calibrated Oculus simulator) with one held-out implementation applied (sonar_realism/diagnose/heldout: two or more
forms per catalogued effect, written without the catalogue's code, plus un-catalogued effects whose right answer
is "residual"). Sim and "real" come from different worlds (other seeds). The diagnosis runs through its public
entry point `diagnose(...)` and is read only through the DESIGN contract keys of diagnosis.json (`read_diagnosis`).

Reported: top-1 on single catalogued effects (the selected effect that alone closes the most; nothing selected is
wrong), share of the gap closed (mean, median; also of the part above the no-effect floor), un-catalogued effects
blamed on a catalogued one, cases reported ambiguous (when the result says so), per family and per implementation;
with `--limits`, the detection limit of a few weak effects (smallest strength found in >= 80 % of the repeats).

    OMP_NUM_THREADS=1 nice -n 10 python bench/bench_diagnose_heldout.py --quick --out heldout.json
    OMP_NUM_THREADS=1 nice -n 10 python bench/bench_diagnose_heldout.py --settings default:40:inside+wide,organic:40
    OMP_NUM_THREADS=1 nice -n 10 python bench/bench_diagnose_heldout.py --limits --quick
    OMP_NUM_THREADS=1 nice -n 10 python bench/bench_diagnose_heldout.py --quick --settings calibrated:24 \
        --calibration oculus   # geometry and scene terms in play: are sensor effects blamed on them?
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from sonar_realism.diagnose import DiagnoseConfig, diagnose
from sonar_realism.diagnose.blind_forms import BLIND
from sonar_realism.diagnose.heldout import (
    IMPLEMENTATIONS,
    UNCATALOGUED,
    Implementation,
    Place,
    apply_held_out,
    find_implementation,
)
from sonar_realism.diagnose.scene_terms import SceneStart
from sonar_realism.diagnose.second_blind_forms import SECOND_BLIND
from sonar_realism.diagnose.tuning_forms import TUNING
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import resample_to_grid
from sonar_realism.sim import SensorConfig, simulate
from sonar_realism.sim.calibrated import simulate_calibrated
from sonar_realism.sim.calibration import load_calibration

GRID = (256, 128)  # ranges x beams of every frame here (the calibrated sensor's frames are resampled onto it)
CALIBRATION = "sonar_realism/assets/oculus_calibration.json"
SIM_SEED, REAL_SEED = 11, 22
QUICK_CONFIG = DiagnoseConfig(fit_frames=6, eval_frames=16, real_frames=16, bootstrap=50)
FULL_SETTINGS = "default:40:inside+wide,organic:40,calibrated:40,default:500:inside:first"
QUICK_SETTINGS = "default:24"
# the validation sets `--half` picks: never tuned against, tuned against, written blind later (a fresh held-out),
# and a second set written blind after the third had been run (another fresh held-out)
HALVES: dict[str, dict[str, Implementation]] = {"held-out": IMPLEMENTATIONS, "tuning": TUNING, "blind": BLIND,
                                                "blind2": SECOND_BLIND}

# Detection-limit sweeps: implementation, the parameter swept (weak to strong), the values, the others held.
LIMITS: dict[str, tuple[str, tuple[float, ...], dict[str, float]]] = {
    "beam_sidelobes/chebyshev_coherent": ("sidelobe_db", (-35.0, -30.0, -25.0, -20.0, -15.0),
                                          {"mainlobe_deg": 1.0}),
    "ring_down/power_law_recovery": ("amplitude", (0.05, 0.1, 0.2, 0.4, 0.8),
                                     {"knee_m": 0.03, "power": 2.5, "suppression": 0.0}),
    "tvg_noise/incoherent_power_law": ("noise_amplitude", (0.01, 0.02, 0.05, 0.1, 0.2),
                                       {"tvg_log_coeff_db": 30.0, "mismatch_db_per_decade": 0.0,
                                        "correlation_ranges": 0.3}),
    "speckle/rician_lognormal": ("diffuse_fraction", (0.05, 0.1, 0.2, 0.4, 0.8),
                                 {"texture_sigma": 0.0, "correlation_beams": 0.6, "correlation_ranges": 0.2}),
}
FOUND_SHARE = 0.8


# --- the one reader of the diagnosis -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Read:
    gap_before: float
    gap_after_selected: float
    selected: list[str]
    ranked: list[tuple[str, float]]  # (name, gap_after alone), in the diagnosis' order
    residual_places: list[dict[str, Any]]  # the residual's entries that carry a range_m or bearing_deg interval
    ambiguous: Any  # the optional `ambiguous` key, None when absent
    setup: list[str]  # selected geometry or scene terms (`selected_effects[i].kind` other than "effect")
    unconfirmed: list[str]  # effects dropped because the real frames lack their signature (optional key)


def read_diagnosis(result: Any) -> Read:
    """Everything this bench learns from a diagnosis, read from diagnosis.json's DESIGN contract keys (plus the
    optional `ambiguous`, `unconfirmed` and `selected_effects[i].kind`): the result object is only asked for its
    JSON form, whatever its Python type."""
    payload = result if isinstance(result, dict) else result.to_json()
    residual = payload.get("residual") or {}
    # places sit in `residual` itself or under `residual.where`; profile bins name their interval `span`
    nested = residual.get("where") if isinstance(residual, dict) else None
    where = nested if isinstance(nested, dict) else residual
    span_as = {"range_bins": "range_m", "bearing_bins": "bearing_deg"}
    places: list[dict[str, Any]] = []
    if isinstance(where, dict):
        for key, entries in where.items():
            if not isinstance(entries, list):
                continue
            for i, e in enumerate(entries):
                if isinstance(e, dict) and "span" in e and key in span_as:
                    e = {**e, span_as[key]: e["span"]}
                if isinstance(e, dict) and ("range_m" in e or "bearing_deg" in e):
                    places.append({"list": key, "rank": i, **e})
    return Read(gap_before=float(payload["gap_before"]), gap_after_selected=float(payload["gap_after_selected"]),
                selected=[str(s) for s in payload["selected"]],
                ranked=[(str(r["name"]), float(r["gap_after"])) for r in payload["ranked_effects"]],
                residual_places=places, ambiguous=payload.get("ambiguous"),
                setup=[str(e["name"]) for e in payload.get("selected_effects") or []
                       if isinstance(e, dict) and e.get("kind", "effect") != "effect"],
                unconfirmed=[str(u["effect"]) for u in payload.get("unconfirmed") or [] if isinstance(u, dict)])


# --- frames ----------------------------------------------------------------------------------------------------------

def clean_frames(scene: str, n: int, seed: int) -> list[SonarImage]:
    """n frames of the simulator without effects: a named scene, or "calibrated" (the shipped Oculus calibration,
    a new view per frame, `--effects none`), all on GRID."""
    if scene == "calibrated":
        frames = [f for f, _ in simulate_calibrated(load_calibration(CALIBRATION), n, seed, chain=[])]
        return [resample_to_grid(f, *GRID) for f in frames]
    sensor = SensorConfig(n_ranges=GRID[0], n_beams=GRID[1], elevation_rays=32)
    return [f for f, _ in simulate(scene=scene, effects="none", n=n, seed=seed, sensor=sensor)]


# --- one case --------------------------------------------------------------------------------------------------------

def top1(read: Read) -> str:
    """The effect the diagnosis names: of the selected, the one that alone leaves the smallest gap ("" if none)."""
    alone = dict(read.ranked)
    return min(read.selected, key=lambda name: alone.get(name, math.inf)) if read.selected else ""


def ambiguous_with(read: Read, named: str) -> list[str]:
    """The effects the diagnosis could not tell `named` from (its ambiguous group's members; [] if none)."""
    groups = [[str(a["effect"]) for a in g["effects"]] for g in read.ambiguous or [] if isinstance(g, dict)]
    return [name for members in groups if named in members for name in members]


def overlaps(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return min(a) <= max(b) and min(b) <= max(a)


def in_place(read: Read, place: Place) -> bool:
    """Whether the residual's top entry of some list lies where the un-catalogued effect is."""
    for entry in (e for e in read.residual_places if e["rank"] == 0):
        if any("range_m" in entry and overlaps(tuple(entry["range_m"]), r) for r in place.range_m):
            return True
        if any("bearing_deg" in entry and overlaps(tuple(entry["bearing_deg"]), b) for b in place.bearing_deg):
            return True
    return False


def run_case(sim: list[SonarImage], real_source: list[SonarImage], implementation: str | None, mode: str,
             params: dict[str, float], config: DiagnoseConfig, seed: int, scene: SceneStart | None = None,
             ) -> dict[str, Any]:
    entry = find_implementation(implementation) if implementation else None
    real = apply_held_out(real_source, implementation, params, seed) if implementation else real_source
    started = time.perf_counter()
    read = read_diagnosis(diagnose(sim, real, config, scene=scene))
    named = top1(read)
    family = entry.family if entry else ""
    row: dict[str, Any] = {
        "implementation": implementation or "none (null)", "family": family or "null", "mode": mode,
        "params": params, "outside_fit_bounds": entry.outside_bounds(params) if entry else [],
        "selected": read.selected, "top1": named, "ranked_first": read.ranked[0][0] if read.ranked else "",
        "gap_before": read.gap_before, "gap_after_selected": read.gap_after_selected,
        "gap_closed": 1.0 - read.gap_after_selected / read.gap_before if read.gap_before > 0 else 0.0,
        "ambiguous": bool(read.ambiguous) if read.ambiguous is not None else None,
        "blamed_on_setup": read.setup, "unconfirmed": read.unconfirmed, "seconds": time.perf_counter() - started}
    if entry and family != UNCATALOGUED:
        row["top1_correct"] = named == family
        row["top1_or_its_group"] = named == family or family in ambiguous_with(read, named)
    if entry and family == UNCATALOGUED:
        row["blamed"] = bool(read.selected)
        row["in_place"] = in_place(read, entry.place(real_source[0], params))
        row["residual_top"] = [e for e in read.residual_places if e["rank"] == 0]
    return row


def parse_settings(text: str) -> list[tuple[str, int, tuple[str, ...], bool]]:
    """"scene:frames[:inside+wide][:first]" comma separated -> (scene, frames, modes, first form only)."""
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        parts = item.split(":")
        modes = tuple(parts[2].split("+")) if len(parts) > 2 and parts[2] else ("inside",)
        if set(modes) - {"inside", "wide"}:
            raise SystemExit(f"--settings {item}: modes are inside and/or wide")
        out.append((parts[0], int(parts[1]), modes, len(parts) > 3 and parts[3] == "first"))
    return out


def implementations(first_only: bool, only: tuple[str, ...] = (),
                    registry: dict[str, Implementation] = IMPLEMENTATIONS) -> list[str]:
    """The implementations of `registry` a setting runs: all, or the first form of each family (and every
    un-catalogued effect); `only` keeps those whose name contains one of its strings."""
    seen: set[str] = set()
    keep = []
    for name, entry in registry.items():
        if (not first_only or entry.family == UNCATALOGUED or entry.family not in seen) and (
                not only or any(part in name for part in only)):
            keep.append(name)
        seen.add(entry.family)
    return keep


def accuracy(settings: str, config: DiagnoseConfig, log: Callable[[str], None],
             keep: Callable[[list[dict[str, Any]]], None] = lambda rows: None, only: tuple[str, ...] = (),
             scene: SceneStart | None = None, registry: dict[str, Implementation] = IMPLEMENTATIONS,
             ) -> list[dict[str, Any]]:
    """Every case of every setting (implementations of `registry`: one of HALVES); `keep` sees the
    rows so far after each case (a long run's partial results)."""
    rows: list[dict[str, Any]] = []
    for scene_name, n, modes, first_only in parse_settings(settings):
        sim = clean_frames(scene_name, n, SIM_SEED)
        real_source = clean_frames(scene_name, n, REAL_SEED)
        draws = np.random.default_rng([2026, n, len(scene_name)])
        cases: list[tuple[str | None, str]] = [(None, "null")]
        cases += [(name, mode) for mode in modes for name in implementations(first_only, registry=registry)]
        kept = set(implementations(first_only, only, registry))
        for index, (name, mode) in enumerate(cases):
            # every case draws, so a case run with --only gets the parameters and seed it has in the full run
            params = registry[name].draw(mode, draws) if name else {}  # type: ignore[arg-type]
            if name and name not in kept:
                continue
            row = {"scene": scene_name, "frames": n,
                   **run_case(sim, real_source, name, mode, params, config, index, scene)}
            rows.append(row)
            keep(rows)
            log(f"{scene_name}:{n} {row['implementation']:42s} {mode:6s} top1={row['top1'] or '-':18s} "
                f"selected={','.join(row['selected']) or '-':34s} closed={100 * row['gap_closed']:6.1f}% "
                f"{row['seconds']:.0f}s")
    return rows


def limits(config: DiagnoseConfig, repeats: int, n: int, quick: bool, log: Callable[[str], None],
           keep: Callable[[list[dict[str, Any]]], None] = lambda rows: None) -> list[dict[str, Any]]:
    """Each sweep value `repeats` times, each repeat with other sim/real worlds and per-ping draws; plus as many
    no-effect runs (how often something is found with nothing there)."""
    worlds = [(clean_frames("default", n, SIM_SEED + 100 * k), clean_frames("default", n, REAL_SEED + 100 * k))
              for k in range(repeats)]
    rows = []
    for k, (sim, real_source) in enumerate(worlds):
        row = run_case(sim, real_source, None, "null", {}, config, k)
        rows.append({"implementation": "none (null)", "value": None, "repeat": k, "found": bool(row["selected"]),
                     "selected": row["selected"], "seconds": row["seconds"]})
        log(f"limits null repeat {k}: selected={','.join(row['selected']) or '-'}")
    for name, (param, values, held) in LIMITS.items():
        family = IMPLEMENTATIONS[name].family
        for value in (values[::2] if quick else values):
            for k, (sim, real_source) in enumerate(worlds):
                row = run_case(sim, real_source, name, "sweep", {**held, param: value}, config, 1000 + k)
                rows.append({"implementation": name, "family": family, "param": param, "value": value, "repeat": k,
                             "found": family in row["selected"], "selected": row["selected"],
                             "gap_closed": row["gap_closed"], "seconds": row["seconds"]})
                keep(rows)
                log(f"limits {name} {param}={value} repeat {k}: selected={','.join(row['selected']) or '-'}")
    return rows


# --- summaries -------------------------------------------------------------------------------------------------------

def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    singles = [r for r in rows if "top1_correct" in r]
    uncatalogued = [r for r in rows if "blamed" in r]
    floors = {(r["scene"], r["frames"]): r["gap_before"] for r in rows if r["family"] == "null"}
    for r in singles:
        closable = r["gap_before"] - floors.get((r["scene"], r["frames"]), 0.0)
        r["gap_closed_of_closable"] = ((r["gap_before"] - r["gap_after_selected"]) / closable if closable > 0
                                       else math.nan)
    closed = [r["gap_closed"] for r in singles]
    closable = [r["gap_closed_of_closable"] for r in singles if np.isfinite(r["gap_closed_of_closable"])]
    ambiguous_known = any(r["ambiguous"] is not None for r in rows)

    def group(key: str) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for r in singles + uncatalogued:
            g = out.setdefault(r[key], {"cases": 0, "top1": 0, "closed": [], "blamed": 0, "in_place": 0,
                                        "ambiguous": 0, "named": {}})
            g["cases"] += 1
            g["top1"] += int(r.get("top1_correct", False))
            g["blamed"] += int(r.get("blamed", False))
            g["in_place"] += int(r.get("in_place", False))
            g["ambiguous"] += int(bool(r["ambiguous"]))
            g["closed"].append(r["gap_closed"])
            g["named"][r["top1"] or "-"] = g["named"].get(r["top1"] or "-", 0) + 1
        for g in out.values():
            g["closed_mean"] = _mean(g.pop("closed"))
        return out

    return {"top1_single": _mean([float(r["top1_correct"]) for r in singles]), "singles": len(singles),
            "top1_inside": _mean([float(r["top1_correct"]) for r in singles if r["mode"] == "inside"]),
            "top1_wide": _mean([float(r["top1_correct"]) for r in singles if r["mode"] == "wide"]),
            "top1_or_its_group_single": _mean([float(r.get("top1_or_its_group", r["top1_correct"])) for r in singles]),
            "ranked_first_single": _mean([float(r["ranked_first"] == r["family"]) for r in singles]),
            "gap_closed_mean": _mean(closed), "gap_closed_median": float(np.median(closed)) if closed else math.nan,
            "gap_closed_of_closable_mean": _mean(closable),
            "gap_closed_of_closable_median": float(np.median(closable)) if closable else math.nan,
            "uncatalogued_cases": len(uncatalogued),
            "uncatalogued_blamed": sum(r["blamed"] for r in uncatalogued),
            "uncatalogued_in_place": sum(r["in_place"] for r in uncatalogued),
            "ambiguous_reported": (sum(bool(r["ambiguous"]) for r in rows) if ambiguous_known
                                   else "the diagnosis reports no `ambiguous` key"),
            "null_selected": {f"{r['scene']}:{r['frames']}": r["selected"] for r in rows if r["family"] == "null"},
            "setup_blamed": sum(bool(r.get("blamed_on_setup")) for r in rows),
            "per_family": group("family"), "per_implementation": group("implementation")}


def limit_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    nulls = [r for r in rows if r["value"] is None]
    out: dict[str, Any] = {"null_found_share": _mean([float(r["found"]) for r in nulls]), "sweeps": {}}
    for name, (param, values, _) in LIMITS.items():
        rates = {}
        for value in values:
            hits = [r["found"] for r in rows if r["implementation"] == name and r["value"] == value]
            if hits:
                rates[value] = float(np.mean(hits))
        found = [v for v, share in rates.items() if share >= FOUND_SHARE]
        # weakest value found in >= 80 % of repeats (values are listed weak to strong)
        out["sweeps"][name] = {"param": param, "found_share": rates, "detection_limit": found[0] if found else None}
    return out


def _pct(value: float) -> str:
    return "n/a" if not np.isfinite(value) else f"{100 * value:.0f}%"


def print_accuracy(summary: dict[str, Any]) -> None:
    print("\n| measure | value | goal (issue 13) |\n|---|---|---|")
    print(f"| top-1 on single catalogued effects (all / inside / wide draws) | {_pct(summary['top1_single'])} / "
          f"{_pct(summary['top1_inside'])} / {_pct(summary['top1_wide'])} of {summary['singles']} | >= 90% |")
    print(f"| top-1 right, or the hidden family in the ambiguous group of the name (\"one of these\") | "
          f"{_pct(summary['top1_or_its_group_single'])} | - |")
    print(f"| ranked_effects[0] is the hidden family | {_pct(summary['ranked_first_single'])} | - |")
    print(f"| gap closed, mean / median | {_pct(summary['gap_closed_mean'])} / "
          f"{_pct(summary['gap_closed_median'])} | >= 70% mean |")
    print(f"| gap closed of the part above the no-effect floor, mean / median | "
          f"{_pct(summary['gap_closed_of_closable_mean'])} / {_pct(summary['gap_closed_of_closable_median'])} | - |")
    print(f"| un-catalogued effects blamed on a catalogued one | {summary['uncatalogued_blamed']} of "
          f"{summary['uncatalogued_cases']} | 0 |")
    print(f"| un-catalogued: residual's top place where the effect is | {summary['uncatalogued_in_place']} of "
          f"{summary['uncatalogued_cases']} | all |")
    print(f"| cases reported ambiguous | {summary['ambiguous_reported']} | - |")
    print(f"| no-effect runs: selected | {summary['null_selected']} | nothing |")
    print(f"| cases with a geometry or scene term selected (with --calibration) | {summary['setup_blamed']} | - |")
    for title, key in (("family", "per_family"), ("implementation", "per_implementation")):
        print(f"\n| {title} | cases | top-1 right | blamed (un-catalogued) | residual in place | gap closed (mean) "
              f"| ambiguous | named (top-1) |\n|---|---|---|---|---|---|---|---|")
        for name, g in summary[key].items():
            named = ", ".join(f"{k} {v}" for k, v in sorted(g["named"].items(), key=lambda kv: -kv[1]))
            print(f"| {name} | {g['cases']} | {g['top1']} | {g['blamed']} | {g['in_place']} | "
                  f"{_pct(g['closed_mean'])} | {g['ambiguous']} | {named} |")


def print_limits(summary: dict[str, Any], repeats: int) -> None:
    print(f"\n| effect (implementation, swept parameter) | found share per value ({repeats} repeats) | "
          f"detection limit (found >= {FOUND_SHARE:.0%}) |\n|---|---|---|")
    for name, s in summary["sweeps"].items():
        shares = ", ".join(f"{v:g}: {share:.0%}" for v, share in s["found_share"].items())
        limit = "not reached" if s["detection_limit"] is None else f"{s['param']} = {s['detection_limit']:g}"
        print(f"| {name} ({s['param']}) | {shares} | {limit} |")
    print(f"| no effect (false finds) | {_pct(summary['null_found_share'])} | - |")


def run(quick: bool = True) -> list[dict[str, Any]]:
    """For bench/run.py (by name only: minutes long): one row per implementation, then the summary."""
    config = QUICK_CONFIG if quick else DiagnoseConfig()
    summary = summarise(accuracy(QUICK_SETTINGS if quick else FULL_SETTINGS, config, lambda message: None))
    rows = [{"implementation": name, **{k: v for k, v in g.items() if k != "named"}}
            for name, g in summary["per_implementation"].items()]
    return rows + [{"implementation": "summary", **{k: v for k, v in summary.items() if not k.startswith("per_")}}]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"small diagnosis config, settings {QUICK_SETTINGS!r} (limits: 1st, 3rd, 5th value)")
    parser.add_argument("--settings", help=f"scene:frames[:inside+wide][:first],... (full default: {FULL_SETTINGS})")
    parser.add_argument("--only", default="", help="run only implementations whose name contains one of these "
                                                   "comma-separated strings (e.g. range_blur,column_stripes), with "
                                                   "the parameters they have in the full run")
    parser.add_argument("--half", choices=tuple(HALVES), default="held-out",
                        help="which implementations: the held-out half (never tuned against), the tuning set "
                             "(diagnose/tuning_forms.py) or the blind set (diagnose/blind_forms.py)")
    parser.add_argument("--limits", action="store_true", help="detection-limit sweeps instead of the accuracy run")
    parser.add_argument("--repeats", type=int, default=3, help="repeats per sweep value (--limits)")
    parser.add_argument("--limit-frames", type=int, default=24, help="frames per set in the sweeps (--limits)")
    parser.add_argument("--out", help="write the rows and the summary here as JSON")
    parser.add_argument("--calibration", help="geometry and scene terms in play, started from this CALIB.json (or "
                                              "oculus): every row then says which were selected (blamed_on_setup)")
    args = parser.parse_args()
    config = QUICK_CONFIG if args.quick else DiagnoseConfig()
    started = time.perf_counter()

    def log(message: str) -> None:
        print(f"[{time.perf_counter() - started:6.0f}s] {message}", file=sys.stderr, flush=True)

    def keep(rows: list[dict[str, Any]]) -> None:
        if args.out:
            with open(args.out, "w") as handle:
                json.dump({"partial": True, "rows": rows}, handle, indent=2, default=str)

    if args.limits:
        rows = limits(config, args.repeats, args.limit_frames, args.quick, log, keep)
        summary = limit_summary(rows)
        print_limits(summary, args.repeats)
    else:
        only = tuple(filter(None, (s.strip() for s in args.only.split(","))))
        scene = SceneStart.from_calibration(load_calibration(args.calibration)) if args.calibration else None
        rows = accuracy(args.settings or (QUICK_SETTINGS if args.quick else FULL_SETTINGS), config, log, keep, only,
                        scene, HALVES[args.half])
        summary = summarise(rows)
        print_accuracy(summary)
    run_info = {"command": " ".join(sys.argv), "seconds": time.perf_counter() - started, "grid": list(GRID),
                "config": dataclasses.asdict(config), "machine": platform.processor() or platform.machine(),
                "cpus": os.cpu_count(), "load_after": os.getloadavg()}
    print(f"\nwall time {run_info['seconds']:.0f} s; load after {run_info['load_after'][0]:.2f}")
    if args.out:
        with open(args.out, "w") as handle:
            json.dump({"run": run_info, "summary": summary, "rows": rows}, handle, indent=2, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
