"""Writes an evaluation: results.json, one self-contained HTML page (and the same as Markdown: Table I beside the
paper's, the further metrics) and its matplotlib figures."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sonar_realism import plots
from sonar_realism.evaluate.realism import PAPER_TABLE_I
from sonar_realism.evaluate.suite import RAW_SIM, REAL_HELD_OUT, REAL_OTHER, SuiteResult
from sonar_realism.report_html import Figure, Row, Section, Table, Text, to_markdown, write_html

GRID_INPUTS_PER_CATEGORY = 2


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}"


def _paper_key(method: str) -> str | None:
    lowered = method.lower()
    for key in ("raw sim", "cyclegan", "cdfcvae"):
        if key in lowered:
            return key
    return None


def table_i(summary: dict[str, Any]) -> Table:
    """Table I: one row per category, one column per method; cells "p10–p90, mean [95 % CI]" and the paper's."""
    table = summary["table"]
    methods = list(table["all"])
    rows = []
    for category, row in table.items():
        cells = []
        for method in methods:
            cell = row.get(method)
            if cell is None:
                cells.append("–")
                continue
            text = f"{cell['p10']:.3f}–{cell['p90']:.3f}\nmean {cell['mean']:.3f} [{cell['ci_low']:.3f}, " \
                   f"{cell['ci_high']:.3f}] (n={cell['n']})"
            paper = PAPER_TABLE_I.get(category, {}).get(_paper_key(method) or "")
            if paper:
                text += f"\npaper {paper[0]:.3f}–{paper[1]:.3f}"
            cells.append(text)
        rows.append([category, *cells])
    return Table(["category", *methods], rows)


def metrics_table(summary: dict[str, Any]) -> Table:
    rows = []
    for name, m in summary["methods"].items():
        diversity = m["diversity"]["relative"] if m["diversity"] else None
        rows.append([name, _fmt(m["c2st"]["accuracy"]), _fmt(m["c2st"]["auc"]),
                     f"{_fmt(m['kid']['mean'], 4)} ± {_fmt(m['kid']['std'], 4)}", _fmt(m["spectral_distance"]),
                     _fmt(m["checkerboard"]), _fmt(m["speckle_distance"]), _fmt(m["histogram_distance"]),
                     _fmt(m["edge_ssim"]), _fmt(m["mask_iou"]), _fmt(diversity)])
    ref = summary["real_reference"]
    rows.append(["real (held out)", "0.5 ideal", "0.5 ideal", "0 ideal", "0", _fmt(ref["checkerboard"]), "0", "0",
                 "–", "–", "–"])
    return Table(["method", "C2ST acc", "C2ST AUC", "KID", "spectral dist", "checkerboard", "speckle dist",
                  "hist EMD", "edge SSIM", "mask IoU", "diversity (rel.)"], rows)


def _figures(result: SuiteResult, out: Path) -> dict[str, Path]:
    art = result.artifacts
    figures = {}
    # Sample grid: per row one sim input, then each translator's samples, then a real reference frame.
    fans, labels = [], []
    translators = [name for name in art["outputs"] if name != RAW_SIM]
    n_cols = 2 + sum(art["outputs"][name].shape[1] for name in translators)
    reference = art["reference"]
    rows, cols = reference.shape[1:]
    r0, r1, a0, a1 = art["fan_extent"]
    geometry = (np.linspace(r0, r1, rows), np.linspace(a0, a1, cols))
    for category in sorted(set(art["labels"].tolist())):
        for row, index in enumerate(np.flatnonzero(art["labels"] == category)[:GRID_INPUTS_PER_CATEGORY]):
            fans.append((art["inputs"][index], *geometry))
            labels.append(f"{category}: sim input")
            for name in translators:
                for s, sample in enumerate(art["outputs"][name][index]):
                    fans.append((sample, *geometry))
                    labels.append(f"{name} sample {s + 1}")
            fans.append((reference[(row * 7) % len(reference)], *geometry))
            labels.append("real (held out)")
    figures["samples"] = plots.fan_grid(fans, out / "eval_samples.png", ncols=n_cols, labels=labels, tile_px=200,
                                        colorbar_label="intensity (per-frame max = 1)")
    spectra = art["spectra"]
    figures["spectra"] = plots.line_plot({n: (s.radial_freq[1:], s.radial[1:]) for n, s in spectra.items()},
                                         out / "eval_spectra.png", "Radial power spectrum",
                                         "spatial frequency (cycles per grid cell)", "log10 power")
    figures["spectra_range"] = plots.line_plot(
        {n: (s.range_freq[1:], s.along_range[1:]) for n, s in spectra.items()}, out / "eval_spectra_range.png",
        "Power spectrum along range", "spatial frequency (cycles per range cell)", "log10 power")
    figures["spectra_beam"] = plots.line_plot(
        {n: (s.beam_freq[1:], s.along_beam[1:]) for n, s in spectra.items()}, out / "eval_spectra_beam.png",
        "Power spectrum across beams", "spatial frequency (cycles per beam cell)", "log10 power")
    figures["histograms"] = plots.line_plot(dict(art["histograms"].items()), out / "eval_histograms.png",
                                            "Intensity histogram", "intensity (per-frame max = 1)",
                                            "density (log scale)", logy=True)
    table = result.summary["table"]["all"]
    reals = [n for n in (REAL_OTHER, REAL_HELD_OUT) if n in table]
    names = [n for n in table if n not in reals] + reals
    figures["table"] = plots.bar_plot(names, [table[n]["mean"] for n in names], out / "eval_table.png",
                                      "Realism CNN score (mean with 95% CI)", "P(real)",
                                      errors=[(table[n]["ci_high"] - table[n]["ci_low"]) / 2 for n in names])
    return figures


def write_report(result: SuiteResult, out: str | Path, inputs: dict[str, Any]) -> Path:
    """Write results.json, report.html (self-contained), report.md and the figures into `out`; returns the
    HTML page's path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figures = _figures(result, out)
    summary = {**result.summary, "inputs": inputs, "figures": {k: Path(v).name for k, v in figures.items()}}
    (out / "results.json").write_text(json.dumps(summary, indent=2, default=float))
    data = summary["data"]
    page = [
        Section("Data", [Text(
            f"Real frames: {inputs.get('real')} ({data['n_real']}: {data['n_real_cnn']} train the realism CNN, "
            f"{data['n_real_reference']} are the held-out reference). Simulated inputs: {data['n_sim_cnn']} train "
            f"the CNN, {data['n_sim_scored']} are scored ({data['sim_scored_per_category']}). Models: "
            f"{', '.join(f'{k} = {v}' for k, v in inputs.get('models', {}).items()) or 'none'}."),
            Figure(figures["samples"], "per row: a simulated input, each translator's samples, a held-out real "
                                       "frame (all on the model grid, drawn as fans)")]),
        Section("Table I: realism CNN score (P(real) per input, averaged over its samples)", [
            Text("Cells: 10th–90th percentile over inputs, mean with 95 % bootstrap CI; the paper's range below "
                 "where it has one. The CNN never saw a scored image."),
            table_i(summary), Figure(figures["table"], "realism CNN score per method", width_percent=70)]),
        Section("Further metrics (against the held-out real frames)", [
            Text("C2ST: held-out balanced accuracy / AUC of a fresh classifier (0.5 = indistinguishable). KID on the "
                 "realism CNN's features (0 = same distribution). Spectral distance: mean |Δ log10 radial power|. "
                 "Checkerboard: peak at periods 2/4 cells in decades over its neighbours. Speckle dist: mean "
                 "|Δ contrast| per range band. Hist EMD: earth mover's distance of intensities. Edge SSIM and mask "
                 "IoU: structure kept from the sim input. Diversity: pairwise L1 of samples of one input over that "
                 "between inputs."),
            metrics_table(summary),
            Row([Figure(figures["spectra"], "radial power spectrum"),
                 Figure(figures["histograms"], "intensity histogram")]),
            Row([Figure(figures["spectra_range"], "power spectrum along range"),
                 Figure(figures["spectra_beam"], "power spectrum across beams")])]),
    ]
    (out / "report.md").write_text(to_markdown("Realism evaluation", page))
    return write_html(out / "report.html", "Realism evaluation", page,
                      subtitle=f"`{inputs['command']}`" if inputs.get("command") else "")
