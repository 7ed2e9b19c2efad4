"""diagnosis.json, one self-contained HTML page (and the same as Markdown) with the figures it shows
(matplotlib PNGs via sonar_realism.plots)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from sonar_realism import plots
from sonar_realism.diagnose.diagnosis import Diagnosis
from sonar_realism.diagnose.where import level_names
from sonar_realism.diagnose.which import Step
from sonar_realism.report_html import Figure, Row, Section, Table, Text, to_markdown, write_html


def write_report(diagnosis: Diagnosis, out_dir: str | Path, title: str = "Sim-to-real gap diagnosis") -> Path:
    """Write diagnosis.json, report.html (self-contained), report.md and the figures into `out_dir`; return the
    HTML page's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "diagnosis.json").write_text(json.dumps(_jsonable(diagnosis.to_json()), indent=2) + "\n")
    page = sections(diagnosis, write_figures(diagnosis, out))
    (out / "report.md").write_text(to_markdown(title, page))
    return write_html(out / "report.html", title, page)


def write_figures(diagnosis: Diagnosis, out: Path, prefix: str = "diag_") -> dict[str, Path]:
    s = diagnosis.summary
    cell_max = float(max(diagnosis.maps_before.cells.max(), diagnosis.maps_after.cells.max(), 1e-9))
    ranked = s["ranked_effects"]
    path = diagnosis.path
    grid = s["grid"]
    extent = (*grid["bearing_deg"], *grid["range_m"])
    ranges = np.linspace(*grid["range_m"], grid["n_ranges"])
    bearings = np.radians(np.linspace(*grid["bearing_deg"], grid["n_beams"]))
    unit = "gap (held-out)"
    before, after = diagnosis.maps_before, diagnosis.maps_after
    figs = {
        "families": plots.grouped_bar_plot(
            list(diagnosis.family_before), {"before": list(diagnosis.family_before.values()),
                                            "after the selected effects": list(diagnosis.family_after.values())},
            out / f"{prefix}families.png", title="Gap per statistic family", ylabel=unit, size=(960, 440)),
        # an effect that makes things far worse would flatten every other bar: clip at twice the gap before
        "ranking": plots.bar_plot([r["name"] for r in ranked],
                                  [min(r["gap_after"], 2 * s["gap_before"]) for r in ranked],
                                  out / f"{prefix}ranking.png",
                                  title=f"Gap after each effect alone (before: {s['gap_before']:.3g}; bars clipped "
                                        "at 2x)", ylabel=unit, size=(960, 440), reference=("gap before",
                                                                                           s["gap_before"])),
        "curve": plots.line_plot({"held-out gap": (list(range(len(path))), [step.gap for step in path])},
                                 out / f"{prefix}curve.png",
                                 title="Gap along the selection: " + " > ".join(_step_label(step) for step in path),
                                 xlabel="selection step", ylabel=unit),
        "cells_before": plots.heatmap(before.cells, out / f"{prefix}cells_before.png",
                                      title="Gap per range x bearing cell, before", vmin=0.0, vmax=cell_max,
                                      extent=extent, xlabel="bearing (deg)", ylabel="range (m)",
                                      colorbar_label=unit),
        "cells_after": plots.heatmap(after.cells, out / f"{prefix}cells_after.png",
                                     title="Residual gap per range x bearing cell, after the selected effects",
                                     vmin=0.0, vmax=cell_max, extent=extent, xlabel="bearing (deg)",
                                     ylabel="range (m)", colorbar_label=unit),
        "levels": plots.line_plot({"before": (list(range(len(before.levels))), before.levels),
                                   "after": (list(range(len(after.levels))), after.levels)},
                                  out / f"{prefix}levels.png",
                                  title="Gap per intensity level (octaves: " + ", ".join(level_names()) + ")",
                                  xlabel="intensity level (0 = darkest octave)", ylabel=unit),
        "bands": plots.line_plot({"along range, before": (list(range(len(before.bands_range))), before.bands_range),
                                  "across beams, before": (list(range(len(before.bands_beam))), before.bands_beam),
                                  "along range, after": (list(range(len(after.bands_range))), after.bands_range),
                                  "across beams, after": (list(range(len(after.bands_beam))), after.bands_beam)},
                                 out / f"{prefix}bands.png", title="Gap per spatial-frequency octave band",
                                 xlabel="octave band (0 = finest detail)", ylabel=unit),
        "examples": plots.fan_grid([(np.sqrt(diagnosis.examples[k]), ranges, bearings)
                                    for k in ("sim", "corrected", "real")], out / f"{prefix}examples.png", ncols=3,
                                   labels=["sim (raw)", "sim + selected effects", "real"],
                                   colorbar_label="sqrt(normalised intensity)"),
    }
    return figs


def sections(diagnosis: Diagnosis, figures: dict[str, Path]) -> list[Section]:
    s = diagnosis.summary
    res = s["residual"]
    overview = Text(
        f"Sim frames: {s['frames']['sim']}, real frames: {s['frames']['real']} (grid {s['grid']['n_ranges']} ranges "
        f"x {s['grid']['n_beams']} beams; normalisation: {s['normalize']}). Every gap below is measured on held-out "
        "frames; effect parameters were fitted on the other split.\n\n"
        f"**Gap before: {s['gap_before']:.3g}** (95% CI {s['gap_before_ci95'][0]:.3g} to "
        f"{s['gap_before_ci95'][1]:.3g}; classifier two-sample AUC {s['classifier_auc_before']['auc']:.3f}). "
        f"After the selected effects ({', '.join(s['selected']) or 'none'}): **{s['gap_after_selected']:.3g}** "
        f"(CI {s['gap_after_selected_ci95'][0]:.3g} to {s['gap_after_selected_ci95'][1]:.3g}, "
        f"AUC {s['classifier_auc_after_selected']['auc']:.3f}), i.e. **{100 * s['gap_closed']:.0f}% of the gap "
        f"closed**.\n\nGap unit: {s['gap_measure']}.")
    families = Table(["family", "before", "after selected"],
                     [[family, f"{before:.3g}", f"{diagnosis.family_after[family]:.3g}"]
                      for family, before in diagnosis.family_before.items()])
    ranking = Table(["rank", "effect", "held-out gap after", "gap closed", "fitted parameters"],
                    [[i, r["name"], f"{r['gap_after']:.3g}", f"{100 * r['gap_closed']:.0f}%", _params(r["params"])]
                     for i, r in enumerate(s["ranked_effects"], 1)])
    steps = Table(["step", "action", "effect", "held-out gap", "gap closed"],
                  [[i, step["step"], step["effect"], f"{step['gap']:.3g}", f"{100 * step['gap_closed']:.0f}%"]
                   for i, step in enumerate(s["selection_path"])])
    stand_ins = [Text(f"Not blamed: **{stand_in['effect']}** did no better than a plain gain difference (level "
                      f"{stand_in['gain_profile']['level_db']:+.1f} dB, ramp {stand_in['gain_profile']['ramp_db']:+.1f}"
                      f" dB over range: held-out gap {stand_in['gap_with_gain_profile']:.3g} against "
                      f"{stand_in['gap_with_effect']:.3g} with the effect), so its part of the gap is left in the "
                      "residual: a gain pattern the catalogue lacks, or the sim's intensity scale.")
                 for stand_in in s["gain_stand_ins"]]
    residual = Text(
        f"Size {res['size']:.3g} ({100 * res['fraction_of_gap_before']:.0f}% of the gap before; "
        f"{'significant' if res['significant'] else 'not significant'}: the 95% CI "
        f"{'excludes' if res['significant'] else 'includes'} 0). Families holding it: "
        + ", ".join(f"{f['name']} ({100 * f['share']:.0f}%)" for f in res["families"][:3]) + ".")
    return [
        Section("Gap", [overview, families, Figure(figures["families"], "gap per statistic family, before and "
                                                                        "after the selected effects")]),
        Section("Where (before any correction)", [
            Text("\n".join(_where_lines(s["where_before"]))),
            Row([Figure(figures["cells_before"], "gap per range x bearing cell"),
                 Figure(figures["levels"], "gap per intensity level")]),
            Figure(figures["bands"], "gap per octave band", width_percent=60)]),
        Section("Which effect: each catalogued effect fitted alone", [
            ranking, Figure(figures["ranking"], "held-out gap after each effect alone")]),
        Section("How far: greedy forward selection, backward pruning, the gain check", [
            Text("Each step adds the effect that lowers the held-out gap most (significantly); pruning then drops an "
                 "effect the later ones make redundant, and an effect that does no better than a plain gain "
                 "difference is not blamed."),
            steps, Text(f"Selection stopped: {s['selection_stopped']}."), *stand_ins,
            Figure(figures["curve"], "held-out gap along the selection", width_percent=70)]),
        Section("Residual: what no catalogued effect explains", [
            residual, Text("\n".join(_where_lines(res))),
            Figure(figures["cells_after"], "residual gap per range x bearing cell", width_percent=60),
            Figure(figures["examples"], "one held-out frame: sim, sim with the selected effects, real")]),
    ]


def _params(params: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items())


def _step_label(step: Step) -> str:
    return {"add": "+", "remove": "-", "gain_stand_in": "-", "refit": "refit "}.get(step.action, "") + step.effect


def _where_lines(where: dict[str, Any]) -> list[str]:
    cells = "; ".join(f"range {c['range_m'][0]:.3g}-{c['range_m'][1]:.3g} m, bearing {c['bearing_deg'][0]:.3g} to "
                      f"{c['bearing_deg'][1]:.3g} deg ({100 * c['share']:.0f}%)" for c in where["cells"])
    levels = ", ".join(f"{lv['name']} counts ({100 * lv['share']:.0f}%)" for lv in where["levels"])
    bands_r = ", ".join(f"{b['name']} ({100 * b['share']:.0f}%)" for b in where["bands_range"])
    bands_b = ", ".join(f"{b['name']} ({100 * b['share']:.0f}%)" for b in where["bands_beam"])
    ranges = "; ".join(f"{b['range_m'][0]:.3g}-{b['range_m'][1]:.3g} m ({100 * b['share']:.0f}%)"
                       for b in where.get("range_bins", []))
    bearings = "; ".join(f"{b['bearing_deg'][0]:.3g} to {b['bearing_deg'][1]:.3g} deg ({100 * b['share']:.0f}%)"
                         for b in where.get("bearing_bins", []))
    return [f"Cells: {cells or 'none stands out'}",
            f"Mean brightness, range bins: {ranges or 'none stands out'}; bearing bins: {bearings or 'none'}",
            f"Intensity levels: {levels}",
            f"Spatial periods along range: {bands_r}; across beams: {bands_b}"]


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
