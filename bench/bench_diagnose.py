"""Blind validation of the sim-to-real diagnosis, and its speed on 500 vs 500 frames.

"Real" frames are clean simulated frames with hidden effects added by the alternative implementations in
sonar_realism.diagnose.validation (the same physics by another formula or process); the diagnosis sees only the
frames. Reported: top-1 identification on single effects, recall on pairs, parameter error (fraction of each
parameter's search range), the fraction of the gap closed on held-out frames (of the whole gap, and of the part
above the null case's gap: sim and "real" come from different worlds), whether anything is selected when nothing
is hidden, what happens with withheld effects that are not in the catalogue (selected? residual in the right
place?), which cases were reported as ambiguous, and the wall time of 500 vs 500 diagnoses at 512 ranges x 256
beams (2 hidden effects, and the 4-effect worst case), each beside the same diagnosis without remembered draws
(sim/repeated_draws.py) in the same run.

    nice python bench/bench_diagnose.py [--quick] [--skip-timing | --skip-accuracy] [--cases A,B] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time

import numpy as np

from sonar_realism.diagnose import DiagnoseConfig, Diagnosis, diagnose
from sonar_realism.diagnose.validation import WITHHELD, blind_run, draw_hidden, make_real
from sonar_realism.sim import SensorConfig, simulate
from sonar_realism.sim.effects import PIPELINE_ORDER
from sonar_realism.sim.repeated_draws import remembering_draws

PAIRS = [("speckle", "tvg_noise"), ("beam_sidelobes", "gamma_quantization"), ("range_blur", "ring_down"),
         ("multipath", "speckle"), ("motion_blur", "tvg_noise"), ("elevation_spread", "interference"),
         ("speckle", "gamma_quantization"), ("ring_down", "beam_sidelobes")]
WITHHELD_PARAMS = {"lens_reflection": {"at_fraction": 0.62, "width_fraction": 0.02, "amplitude": 0.45},
                   "beam_gain_ripple": {"vignetting_power": 6.0, "ripple": 0.25}}


def frames(n: int, seed: int, sensor: SensorConfig) -> list:
    return [frame for frame, _ in simulate(n=n, seed=seed, sensor=sensor)]


def accuracy_suite(n_frames: int, config: DiagnoseConfig, sensor: SensorConfig, pairs: int,
                   only: set[str] | None = None, log=print) -> list[dict]:
    """Every blind case (the null case, each effect alone, `pairs` pairs, the withheld effects); with `only`, just
    the cases of those names (hidden parameters are drawn as in the full suite, so a case is the same either
    way)."""
    sim = frames(n_frames, 11, sensor)
    real_source = frames(n_frames, 22, sensor)
    rng = np.random.default_rng(2024)
    # The null case (no hidden effect) measures the floor: sim and "real" come from different worlds, so their
    # statistics differ even without any sensor effect; no effect should be selected there.
    cases = ([[]] + [[name] for name in PIPELINE_ORDER] + [list(p) for p in PAIRS[:pairs]]
             + [[w] for w in WITHHELD])
    rows = []
    for index, case in enumerate(cases):
        hidden = {name: WITHHELD_PARAMS[name] if name in WITHHELD else draw_hidden(name, rng) for name in case}
        name = "+".join(case) or "none (null)"
        if only is not None and name not in only:
            continue
        started = time.perf_counter()
        blind = blind_run(sim, real_source, hidden, config, seed=index)
        d = blind.diagnosis
        kind = ("null" if not case else "withheld" if case[0] in WITHHELD else
                "single" if len(case) == 1 else "pair")
        row = {"case": name, "kind": kind, "hidden": hidden, "top1": d.top1, "selected": list(d.selected),
               "verdict": d.verdict, "ambiguous": [[a.effect for a in g.effects] for g in d.ambiguous],
               "stability": {e.name: e.stability for e in d.selected_effects},
               "top1_frequency": d.ranked_effects[0].top_frequency if d.ranked_effects else None,
               "gap_before": d.gap_before, "gap_after_selected": d.gap_after_selected, "gap_closed": d.gap_closed,
               "param_error": blind.param_error, "top1_correct": d.top1 in case,
               "recall": len(set(d.selected) & set(case)) / max(len(case), 1),
               "selection_path": [f"{s.action} {s.effect} {s.gap:.3f}" for s in d.selection_path],
               "selection_stopped": d.selection_stopped, "residual_significant": d.residual.significant,
               "residual_top_family": d.residual.families[0].name,
               "gain_pattern": d.residual.gain_pattern.describe() if d.residual.gain_pattern else None,
               "wall_s": time.perf_counter() - started}
        if kind == "withheld":
            row.update(withheld_place(case[0], d, sim[0], config))
        rows.append(row)
        log(f"{row['case']:40s} top1={d.top1:18s} selected={','.join(d.selected):40s} "
            f"closed={100 * d.gap_closed:5.1f}% {d.verdict} amb={row['ambiguous']} err={blind.param_error} "
            f"{row['wall_s']:.0f}s")
    return rows


def withheld_place(name: str, d: Diagnosis, frame, config: DiagnoseConfig) -> dict:
    """Where a withheld effect's residual should be, and whether the diagnosis put it there.
    lens_reflection: a band at a fixed range, so the top residual range bin must hold the band's centre (within
    one bin); beam_gain_ripple: vignetting darkens the fan's edges most, so the top residual cell must lie in the
    first or last bearing cell."""
    if name == "lens_reflection":
        r = frame.ranges_m
        centre = float(r[0] + WITHHELD_PARAMS[name]["at_fraction"] * (r[-1] - r[0]))
        bins = d.residual.where.range_bins
        width = (r[-1] - r[0]) / config.statistics.profile_bins
        hit = bool(bins) and bool(bins[0].span[0] - width <= centre <= bins[0].span[1] + width)
        return {"expected_place": f"range {centre:.2f} m (top residual range bin)", "in_place": hit}
    cells = d.residual.where.cells
    hit = bool(cells) and cells[0].bearing_cell in (0, config.where.bearing_cells - 1)
    return {"expected_place": "fan edges (top residual cell in the first or last bearing cell)", "in_place": hit}


def summarise(rows: list[dict]) -> dict:
    singles = [r for r in rows if r["kind"] == "single"]
    pairs = [r for r in rows if r["kind"] == "pair"]
    catalogued = singles + pairs
    errors = [e for r in singles for e in r["param_error"].values() if np.isfinite(e)]
    null = next((r for r in rows if r["kind"] == "null"), None)
    floor = null["gap_before"] if null else 0.0
    # Fraction of the part of the gap that the hidden effects made: the floor (scene difference) is not closable.
    for r in catalogued:
        closable = r["gap_before"] - floor
        closed = r["gap_before"] - r["gap_after_selected"]
        r["gap_closed_of_closable"] = closed / closable if closable > 0 else math.nan
    withheld = {r["case"]: {"selected": r["selected"], "gap_closed": r["gap_closed"],
                            "residual_significant": r["residual_significant"],
                            "residual_top_family": r["residual_top_family"], "gain_pattern": r["gain_pattern"],
                            "expected_place": r["expected_place"], "in_place": r["in_place"]}
                for r in rows if r["kind"] == "withheld"}
    closable = [r["gap_closed_of_closable"] for r in catalogued if np.isfinite(r["gap_closed_of_closable"])]
    return {"top1_single": float(np.mean([r["top1_correct"] for r in singles])) if singles else None,
            "recall_pairs": float(np.mean([r["recall"] for r in pairs])) if pairs else None,
            "exact_set_pairs": (float(np.mean([set(r["selected"]) == set(r["hidden"]) for r in pairs]))
                                if pairs else None),
            # of all effects selected in catalogued cases, the share that was hidden (spurious extras lower it)
            "precision_selected": (float(np.mean([name in r["hidden"] for r in catalogued for name in r["selected"]]))
                                   if any(r["selected"] for r in catalogued) else None),
            "param_error_median": float(np.median(errors)) if errors else None,
            "gap_closed_mean": float(np.mean([r["gap_closed"] for r in catalogued])) if catalogued else None,
            "gap_closed_median": float(np.median([r["gap_closed"] for r in catalogued])) if catalogued else None,
            "null_gap": floor, "null_selected": null["selected"] if null else None,
            "gap_closed_of_closable_mean": float(np.mean(closable)) if closable else None,
            "gap_closed_of_closable_median": float(np.median(closable)) if closable else None,
            "ambiguous_cases": [r["case"] for r in rows if r["ambiguous"]],
            "wrong_confident_top1": [r["case"] for r in singles
                                     if not r["top1_correct"] and r["verdict"] == "selected"],
            "withheld": withheld, "runs": len(rows)}


TIMING_HIDDEN = {
    "2 effects": {"speckle": {"shape_nu": 4.0, "grain_beams": 1.2, "grain_ranges": 0.8},
                  "tvg_noise": {"noise_amplitude": 0.15, "tvg_log_coeff_db": 30.0, "absorption_db_per_m": 0.5}},
    "4 effects (worst case)": {"speckle": {"shape_nu": 4.0, "grain_beams": 1.2, "grain_ranges": 0.8},
                               "tvg_noise": {"noise_amplitude": 0.15, "tvg_log_coeff_db": 30.0,
                                             "absorption_db_per_m": 0.5},
                               "ring_down": {"amplitude": 0.5, "decay_m": 0.2, "beam_ripple": 0.2},
                               "gamma_quantization": {"gain": 1.3, "gamma": 0.55}},
}


def cpu_seconds() -> float:
    """User + system CPU time of this process and its finished workers: what a loaded machine does not inflate."""
    own, workers = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + workers.ru_utime + workers.ru_stime


def timing(n: int, config: DiagnoseConfig, label: str) -> dict:
    """One diagnosis of n vs n frames at the simulator's 512 x 256 grid (frames made before the clock starts), with
    the effects of TIMING_HIDDEN[label] hidden; then the same diagnosis without remembered draws (the baseline: the
    result must be the same)."""
    sensor = SensorConfig()
    hidden = TIMING_HIDDEN[label]
    sim = frames(n, 5, sensor)
    real = make_real(frames(n, 6, sensor), hidden, seed=0)
    started, cpu_started = time.perf_counter(), cpu_seconds()
    result = diagnose(sim, real, config)
    seconds, cpu_s = time.perf_counter() - started, cpu_seconds() - cpu_started
    started = time.perf_counter()
    with remembering_draws(limit_mb=0):
        baseline = diagnose(sim, real, config)
    baseline_s = time.perf_counter() - started
    if {**baseline.to_json(), "seconds": 0} != {**result.to_json(), "seconds": 0}:
        raise AssertionError(f"timing {label}: the diagnosis changed without remembered draws")
    return {"n_sim": n, "n_real": n, "grid": "512 x 256", "hidden": "+".join(hidden), "label": label,
            "seconds": seconds, "cpu_s": cpu_s, "load_1min": os.getloadavg()[0],
            "baseline_no_remembered_draws_s": baseline_s, "time_vs_baseline": seconds / baseline_s,
            "selected": list(result.selected), "gap_closed": result.gap_closed,
            "verdict": result.verdict}


def run(quick: bool = False, skip_timing: bool = False, skip_accuracy: bool = False,
        only: set[str] | None = None) -> list[dict]:
    """Rows: one per blind case, then a summary row and (unless skipped) the 500 vs 500 timing rows."""
    rows: list[dict] = []
    if not skip_accuracy:
        if quick:
            sensor = SensorConfig(n_ranges=256, n_beams=128, elevation_rays=32)
            config = DiagnoseConfig(fit_frames=6, eval_frames=16, real_frames=16, bootstrap=50)
            rows = accuracy_suite(24, config, sensor, pairs=2, only=only)
        else:
            sensor = SensorConfig()
            config = DiagnoseConfig(fit_frames=8, eval_frames=32, real_frames=32, bootstrap=100)
            rows = accuracy_suite(48, config, sensor, pairs=len(PAIRS), only=only)
        rows.append({"case": "summary", **summarise(rows)})
    if not skip_timing:
        rows += [{"case": "timing", **timing(500, DiagnoseConfig(), label)} for label in TIMING_HIDDEN]
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller frames and fewer cases")
    parser.add_argument("--skip-timing", action="store_true")
    parser.add_argument("--skip-accuracy", action="store_true", help="only the 500 vs 500 timing")
    parser.add_argument("--cases", help="only these blind cases, comma separated (e.g. 'range_blur,none (null)')")
    parser.add_argument("--out", help="write all rows as JSON here")
    args = parser.parse_args()
    only = {c.strip() for c in args.cases.split(",")} if args.cases else None
    rows = run(args.quick, args.skip_timing, args.skip_accuracy, only)
    if args.out:
        with open(args.out, "w") as handle:
            json.dump(rows, handle, indent=2, default=float)
    print("\n| measure | value | goal |\n|---|---|---|")
    for r in rows:
        if r["case"] == "timing":
            print(f"| 500 vs 500 frames, 512 x 256, {r['label']}: wall time (CPU time; load; selected; without "
                  f"remembered draws, same run) | {r['seconds']:.0f} s ({r['cpu_s']:.0f} s CPU; load "
                  f"{r['load_1min']:.1f}; {','.join(r['selected']) or 'none'}; "
                  f"{r['baseline_no_remembered_draws_s']:.0f} s, x{r['time_vs_baseline']:.2f}) | <= 120 s |")
    summary = next((r for r in rows if r["case"] == "summary"), None)
    if summary is None:
        return 0
    def pct(value: float | None) -> str:
        return "-" if value is None or not np.isfinite(value) else f"{value:.0%}"

    print(f"| top-1 identification, single effects | {pct(summary['top1_single'])} | >= 90% |")
    if summary["recall_pairs"] is not None:
        print(f"| recall of both effects, pairs | {summary['recall_pairs']:.0%} | - |")
        print(f"| pairs whose selected set is exactly the hidden pair | {summary['exact_set_pairs']:.0%} | - |")
    if summary["precision_selected"] is not None:
        print(f"| selected effects that were hidden (single, pair cases) | {summary['precision_selected']:.0%} | - |")
    print(f"| parameter error (median, fraction of search range) | {summary['param_error_median'] or math.nan:.3f} "
          "| - |")
    print(f"| gap closed on held-out frames (mean / median) | {pct(summary['gap_closed_mean'])} / "
          f"{pct(summary['gap_closed_median'])} | >= 70% |")
    print(f"| null case (no hidden effect): gap (floor) / selected | {summary['null_gap']:.3g} / "
          f"{','.join(summary['null_selected'] or []) or 'none'} | none selected |")
    print(f"| gap closed, of the part above the floor (mean / median) | "
          f"{pct(summary['gap_closed_of_closable_mean'])} / {pct(summary['gap_closed_of_closable_median'])} | - |")
    for name, w in summary["withheld"].items():
        print(f"| withheld {name}: selected / closed / residual family / in place | "
              f"{','.join(w['selected']) or 'none'} / {w['gap_closed']:.0%} / {w['residual_top_family']} / "
              f"{'yes' if w['in_place'] else 'no'} ({w['expected_place']}) | residual, not a wrong effect |")
    print(f"| ambiguous cases (reported as such) | {', '.join(summary['ambiguous_cases']) or 'none'} | - |")
    print(f"| single effects named wrongly and confidently | {', '.join(summary['wrong_confident_top1']) or 'none'} "
          "| none |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
