"""diagnosis.json, one self-contained HTML page (and the same as Markdown) with the figures it shows
(matplotlib PNGs via sonar_realism.plots)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from sonar_realism import plots
from sonar_realism.diagnose.result import Diagnosis, Step, Where, write_diagnosis
from sonar_realism.diagnose.where import level_names
from sonar_realism.report_html import Figure, Row, Section, Table, Text, to_markdown, write_html


def write_report(diagnosis: Diagnosis, out_dir: str | Path, title: str = "Sim-to-real gap diagnosis") -> Path:
    """Write diagnosis.json, report.html (self-contained), report.md and the figures into `out_dir`; return the
    HTML page's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_diagnosis(diagnosis, out / "diagnosis.json")
    page = sections(diagnosis, write_figures(diagnosis, out))
    (out / "report.md").write_text(to_markdown(title, page))
    return write_html(out / "report.html", title, page)


def write_figures(diagnosis: Diagnosis, out: Path, prefix: str = "diag_") -> dict[str, Path]:
    d = diagnosis
    cell_max = float(max(d.maps_before.cells.max(), d.maps_after.cells.max(), 1e-9))
    ranked = d.ranked_effects
    path = d.selection_path
    grid = d.grid
    extent = (*grid.bearing_deg, *grid.range_m)
    ranges = np.linspace(*grid.range_m, grid.n_ranges)
    bearings = np.radians(np.linspace(*grid.bearing_deg, grid.n_beams))
    unit = "gap (held-out)"
    before, after = diagnosis.maps_before, diagnosis.maps_after
    figs = {
        "families": plots.grouped_bar_plot(
            list(d.family_gaps_before), {"before": list(d.family_gaps_before.values()),
                                         "after the selected effects": list(d.family_gaps_after_selected.values())},
            out / f"{prefix}families.png", title="Gap per statistic family", ylabel=unit, size=(960, 440)),
        # an effect that makes things far worse would flatten every other bar: clip at twice the gap before
        "ranking": plots.bar_plot([r.name for r in ranked], [min(r.gap_after, 2 * d.gap_before) for r in ranked],
                                  out / f"{prefix}ranking.png",
                                  title=f"Gap after each effect alone (before: {d.gap_before:.3g}; bars clipped "
                                        "at 2x)", ylabel=unit, size=(960, 440), reference=("gap before",
                                                                                           d.gap_before)),
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
    }
    if d.examples is not None:  # a diagnosis read back from diagnosis.json has no frames
        figs["examples"] = plots.fan_grid(
            [(np.sqrt(image), ranges, bearings) for image in (d.examples.sim, d.examples.corrected, d.examples.real)],
            out / f"{prefix}examples.png", ncols=3, labels=["sim (raw)", "sim + selected effects", "real"],
            colorbar_label="sqrt(normalised intensity)")
    return figs


VERDICTS = {
    "selected": "The selected effects are told apart from every other candidate in the bootstrap resamples.",
    "ambiguous": "**Ambiguous**: at least one step could not tell its candidates apart within the noise; read the "
                 "ambiguous groups below as \"one of these\", not as the name that happened to be picked.",
    "residual_only": "**Residual only**: no catalogued effect closes a significant part of the gap; what there is "
                     "lies in the residual below.",
    "not_enough_frames": "**Not enough frames to tell**: too few held-out frames for the bootstrap to separate any "
                         "candidate; no ranking is given. Give more frames.",
}


def sections(diagnosis: Diagnosis, figures: dict[str, Path]) -> list[Section]:
    d = diagnosis
    res = d.residual
    overview = Text(
        f"Sim frames: {d.frames.sim}, real frames: {d.frames.real} (grid {d.grid.n_ranges} ranges "
        f"x {d.grid.n_beams} beams; normalisation: {d.normalize}). Every gap below is measured on held-out "
        "frames; effect parameters were fitted on the other split.\n\n"
        f"**Gap before: {d.gap_before:.3g}** (95% CI {d.gap_before_ci95[0]:.3g} to "
        f"{d.gap_before_ci95[1]:.3g}; classifier two-sample AUC {d.classifier_auc_before.auc:.3f}). "
        f"After the selected effects ({', '.join(d.selected) or 'none'}): **{d.gap_after_selected:.3g}** "
        f"(CI {d.gap_after_selected_ci95[0]:.3g} to {d.gap_after_selected_ci95[1]:.3g}, "
        f"AUC {d.classifier_auc_after_selected.auc:.3f}), i.e. **{100 * d.gap_closed:.0f}% of the gap "
        f"closed**.\n\n{VERDICTS[d.verdict]}\n\nGap unit: {d.gap_measure}.")
    families = Table(["family", "before", "after selected"],
                     [[family, f"{before:.3g}", f"{d.family_gaps_after_selected[family]:.3g}"]
                      for family, before in d.family_gaps_before.items()])
    ranking = Table(["rank", "candidate", "kind", "held-out gap after", "gap closed", "ranked first in resamples",
                     "fitted parameters"],
                    [[i, r.name, r.kind, f"{r.gap_after:.3g}", f"{100 * r.gap_closed:.0f}%",
                      f"{100 * r.top_frequency:.0f}%",
                      _params(r.params)] for i, r in enumerate(d.ranked_effects, 1)])
    selected = Table(["selected", "kind", "share of the gap before", "chosen in resamples", "fitted parameters"],
                     [[e.name, e.kind, f"{100 * e.share:.0f}%", f"{100 * e.stability:.0f}%", _params(e.params)]
                      for e in d.selected_effects])
    setup = [Text("The sim's set-up, not its sensor: " + "; ".join(
        f"**{e.name}** ({e.kind}) closes {100 * e.share:.0f}% of the gap before" for e in d.blamed_on_setup())
        + ". Change the simulation's mounting or seabed (e.g. simulate from the calibration) before judging the "
        "sensor effects.")] if d.blamed_on_setup() else []
    ambiguous = [Text(f"Step {group.step} is ambiguous: "
                      + "; ".join(f"**{a.effect}** (would close {100 * share:.0f}% of the gap before, chosen in "
                                  f"{100 * a.frequency:.0f}% of {d.bootstrap_resamples} resamples)"
                                  for a, share in zip(group.effects, group.shares, strict=True))
                      + ". The statistics do not tell these apart on these frames.")
                 for group in d.ambiguous]
    steps = Table(["step", "action", "effect", "held-out gap", "gap closed"],
                  [[i, step.action, step.effect, f"{step.gap:.3g}", f"{100 * (1 - step.gap / d.gap_before):.0f}%"
                    if d.gap_before > 0 else "-"] for i, step in enumerate(d.selection_path)])
    stand_ins = [Text(f"Not blamed: **{s.effect}** "
                      + (f"was fitted with its own physics off ({', '.join(s.physics_off)} at the bound), which "
                         "leaves only a gain" if s.physics_off else "did no better than a fixed gain pattern")
                      + f" ({s.gain_pattern.describe()}): held-out gap {s.gap_with_gain_pattern:.3g} with the "
                      f"pattern against {s.gap_with_effect:.3g} with the effect, so its part of the gap is left in the "
                      "residual: a gain pattern the catalogue lacks, or the sim's intensity scale.")
                 for s in d.gain_stand_ins]
    unconfirmed = [Text(f"Held to its signature: **{u.effect}** as first fitted ({_params(u.params)}; held-out gap "
                        f"{u.gap_with_effect:.3g}) has a cross-talk pedestal the real frames do not show, "
                        f"{u.signature}; it competed refitted without it ({u.gap_without:.3g}).")
                   if u.named_instead == u.effect else
                   Text(f"Passed over: **{u.effect}** closed the gap furthest at its step (held-out gap "
                        f"{u.gap_with_effect:.3g} with it, {u.gap_without:.3g} with **{u.named_instead}**), but the "
                        f"real frames lack its signature, {u.signature}. {u.named_instead} is named in its place."
                        if u.named_instead else
                        f"Not blamed: **{u.effect}** closed part of the gap (held-out gap {u.gap_with_effect:.3g} "
                        f"with it, {u.gap_without:.3g} without), but the real frames lack its signature, "
                        f"{u.signature}. What it mimicked is a difference of the scene or the set-up (another "
                        "seabed, other objects) or an effect the catalogue lacks: residual.")
                   for u in d.unconfirmed]
    found = [Text(f"Found by its signature: **{f.effect}** ({f.signature}). The gap does not credit it (held-out "
                  f"gap {f.gap_without:.3g} without it, {f.gap_with_effect:.3g} with it): its parameters are read "
                  "off that signature, not fitted to the gap.")
             for f in d.found]
    pattern = res.gain_pattern
    gain_text = (f"A fixed gain pattern on top of the selected effects closes a further "
                 f"{100 * pattern.share_of_gap:.0f}% of the gap before (held-out gap {pattern.gap:.3g}); it stands "
                 f"out at {pattern.describe()}. No catalogued effect is blamed for it: a channel or range gain "
                 "error, a beam pattern or the sim's intensity scale." if pattern is not None else
                 "A fixed gain pattern explains none of the residual on held-out frames.")
    residual = Text(
        f"Size {res.size:.3g} ({100 * res.fraction_of_gap_before:.0f}% of the gap before; "
        f"{'significant' if res.significant else 'not significant'}: the 95% CI "
        f"{'excludes' if res.significant else 'includes'} 0). Families holding it: "
        + ", ".join(f"{f.name} ({100 * f.share:.0f}%)" for f in res.families[:3]) + ".\n\n" + gain_text)
    residual_figures = [Figure(figures["cells_after"], "residual gap per range x bearing cell", width_percent=60)]
    if "examples" in figures:
        residual_figures.append(Figure(figures["examples"], "one held-out frame: sim, sim with the selected effects, "
                                                            "real"))
    return [
        Section("Gap", [overview, families, Figure(figures["families"], "gap per statistic family, before and "
                                                                        "after the selected effects")]),
        Section("Where (before any correction)", [
            Text("\n".join(_where_lines(d.where_before))),
            Row([Figure(figures["cells_before"], "gap per range x bearing cell"),
                 Figure(figures["levels"], "gap per intensity level")]),
            Figure(figures["bands"], "gap per octave band", width_percent=60)]),
        Section("Which effect: each catalogued effect fitted alone", [
            ranking, Figure(figures["ranking"], "held-out gap after each effect alone")]),
        Section("How far: greedy forward selection, backward pruning, the gain check", [
            Text("Each step adds the effect that lowers the held-out gap most (significantly); pruning then drops an "
                 "effect the later ones make redundant, and an effect that does no better than a fixed gain "
                 "pattern is not blamed. \"Chosen in resamples\": how often the step's pick was the best candidate "
                 f"over {d.bootstrap_resamples} bootstrap resamples of the held-out frames."),
            selected, *setup, *ambiguous, steps, Text(f"Selection stopped: {d.selection_stopped}."), *unconfirmed,
            *found, *stand_ins,
            Figure(figures["curve"], "held-out gap along the selection", width_percent=70)]),
        Section("Residual: what no catalogued effect explains", [
            residual, Text("\n".join(_where_lines(res.where))), *residual_figures]),
    ]


def _params(params: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items())


def _step_label(step: Step) -> str:
    signs = {"add": "+", "found": "+", "remove": "-", "unconfirmed": "-", "gain_stand_in": "-", "refit": "refit "}
    return signs.get(step.action, "") + step.effect


def _where_lines(where: Where) -> list[str]:
    cells = "; ".join(f"range {c.range_m[0]:.3g}-{c.range_m[1]:.3g} m, bearing {c.bearing_deg[0]:.3g} to "
                      f"{c.bearing_deg[1]:.3g} deg ({100 * c.share:.0f}%)" for c in where.cells)
    levels = ", ".join(f"{lv.name} counts ({100 * lv.share:.0f}%)" for lv in where.levels)
    bands_r = ", ".join(f"{b.name} ({100 * b.share:.0f}%)" for b in where.bands_range)
    bands_b = ", ".join(f"{b.name} ({100 * b.share:.0f}%)" for b in where.bands_beam)
    ranges = "; ".join(f"{b.span[0]:.3g}-{b.span[1]:.3g} m ({100 * b.share:.0f}%)" for b in where.range_bins)
    bearings = "; ".join(f"{b.span[0]:.3g} to {b.span[1]:.3g} deg ({100 * b.share:.0f}%)" for b in where.bearing_bins)
    return [f"Cells: {cells or 'none stands out'}",
            f"Mean brightness, range bins: {ranges or 'none stands out'}; bearing bins: {bearings or 'none'}",
            f"Intensity levels: {levels}",
            f"Spatial periods along range: {bands_r}; across beams: {bands_b}"]
