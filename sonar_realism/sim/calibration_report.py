"""The calibration report: one self-contained HTML page (figures inlined as PNG) a person reads at a glance.

Real and calibrated-sim frames side by side as fans, the mean range and bearing profiles, the fingerprint
distances before and after, and every fitted number with its bootstrap interval, plus what was assumed.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sonar_realism.sim.fingerprint import PROFILE_BINS

if TYPE_CHECKING:
    from sonar_realism.sim.calibrate import CalibrationResult
    from sonar_realism.sim.calibration import Calibration


def _figure_png(fig) -> str:  # noqa: ANN001 - a matplotlib Figure
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def _fan_axes(ax, image: np.ndarray, fov_deg: float, title: str) -> None:  # noqa: ANN001
    """Draw a polar [range, beam] image as a fan (range up from the apex), as a sonar display does."""
    n_r, n_b = image.shape
    half = math.radians(fov_deg) / 2
    theta = np.linspace(-half, half, n_b + 1)
    radius = np.linspace(0.0, 1.0, n_r + 1)
    t, r = np.meshgrid(theta, radius)
    ax.pcolormesh(r * np.sin(t), r * np.cos(t), image, cmap="gray", vmin=0.0, vmax=1.0, shading="flat",
                  rasterized=True)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(title, fontsize=8)


def fans_figure(real: list[np.ndarray], examples: dict[str, list[np.ndarray]], fov_deg: float) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = {"real": real, **examples}
    columns = min(4, min(len(v) for v in rows.values()))
    fig, axes = plt.subplots(len(rows), columns, figsize=(2.6 * columns, 2.0 * len(rows)), squeeze=False)
    for i, (name, images) in enumerate(rows.items()):
        for j in range(columns):
            _fan_axes(axes[i, j], images[j], fov_deg, f"{name} {j + 1}")
    fig.tight_layout()
    return _figure_png(fig)


def profiles_figure(result: CalibrationResult) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = (np.arange(PROFILE_BINS) + 0.5) / PROFILE_BINS
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.2))
    for name, fp in result.fingerprints.items():
        style = {"color": "black", "linewidth": 2.0} if name == "real" else {}
        left.plot(x, fp.row_mean, label=name, **style)
        right.plot(x, fp.column_mean, label=name, **style)
    left.set(title="mean brightness against range", xlabel="range / max range", ylabel="mean / frame max")
    right.set(title="mean brightness across the fan", xlabel="beam / beams", ylabel="mean / frame max")
    left.legend(fontsize=7)
    fig.tight_layout()
    return _figure_png(fig)


def _row(name: str, value: float, low: float, high: float, unit: str = "") -> str:
    return (f"<tr><td>{html.escape(name)}</td><td>{value:.4g}{unit}</td>"
            f"<td>{low:.4g} .. {high:.4g}{unit}</td></tr>")


def _texture_said(c: Calibration) -> str:
    if c.texture is None:
        return "the catalogue's speckle"
    if c.learned_texture is None:
        return "the recording's speckle, fitted"
    count = c.learned_texture.generators
    drawn = "a generator" if count == 1 else f"a mixture of {count} generators"
    return (f"{drawn} trained on the simulated levels against the recording ({c.learned_texture.steps} steps"
            f"{'' if count == 1 else ' each'}, critic loss {c.learned_texture.critic_loss:.3f}; 1.386 is a critic at "
            "chance)")


def write_report(result: CalibrationResult, path: str | Path) -> Path:
    """Write the report page; returns its path."""
    c = result.calibration
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    m, s, t = c.mounting, c.seabed, c.targets
    rows = [
        _row("height above seabed", m.height_m.value, m.height_m.low, m.height_m.high, " m"),
        _row("tilt (down)", m.tilt_deg.value, m.tilt_deg.low, m.tilt_deg.high, " deg"),
        _row("heave spread (sd)", m.heave_sd_m.value, m.heave_sd_m.low, m.heave_sd_m.high, " m"),
        _row("pitch spread (sd)", m.pitch_sd_deg.value, m.pitch_sd_deg.low, m.pitch_sd_deg.high, " deg"),
        _row("seabed patch contrast (log amplitude rms)", s.patch_contrast.value, s.patch_contrast.low,
             s.patch_contrast.high),
        _row("seabed patch length along range", s.patch_scale_m.value, s.patch_scale_m.low, s.patch_scale_m.high,
             " m"),
        _row("seabed patch width across the fan", s.patch_width_deg.value, s.patch_width_deg.low,
             s.patch_width_deg.high, " deg"),
        _row("seabed dark share", s.dark_fraction.value, s.dark_fraction.low, s.dark_fraction.high),
        _row("seabed roughness", s.roughness_m.value, s.roughness_m.low, s.roughness_m.high, " m"),
        _row(f"frames with a target ({t.source})", t.present_fraction.value, t.present_fraction.low,
             t.present_fraction.high),
        _row("targets in such a frame", t.count.value, t.count.low, t.count.high),
        _row("target size", t.size_m.value, t.size_m.low, t.size_m.high, " m"),
        _row("target range / max range", t.range_fraction.value, t.range_fraction.low, t.range_fraction.high),
        _row(f"target shadow / seabed beside it (floor {t.shadow_floor:.3g})", t.shadow_level.value,
             t.shadow_level.low, t.shadow_level.high),
    ]
    rows += [_row(f"{p.effect}.{p.name}", p.estimate.value, p.estimate.low, p.estimate.high) for p in c.fitted]
    grids = "".join(f"<tr><td>{g.n_beams}</td><td>{g.n_ranges}</td><td>{g.min_range_m:.3g}..{g.max_range_m:.3g} m"
                    f"</td><td>{g.fov_deg:.4g}</td><td>{g.weight:.2f}</td></tr>" for g in c.grid.modes[:8])
    distances = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.4f}</td></tr>" for k, v in c.distances.items())
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in c.notes)
    gains = (f"range {', '.join(f'{v:+.1f}' for v in c.range_gain_db)} dB; "
             f"bearing {', '.join(f'{v:+.1f}' for v in c.bearing_gain_db)} dB")
    ring = c.effects["ring_down"]
    near_field = (f"ring-down amplitude {ring['amplitude']:.3g}, decay {ring['decay_m']:.3g} m, receiver rise "
                  f"{ring.get('rise_m', 0.0):.3g} m (matched on the recording's band profile; no interval)")
    fans = fans_figure(result.real_images, result.examples, c.grid.modes[0].fov_deg)
    texture = _texture_said(c)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>Calibration: {html.escape(c.source)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:2px 8px;font-size:13px}}</style></head><body>
<h1>Simulator calibration: {html.escape(c.source)}</h1>
<p>{c.frames} frames; CALIB.json version {c.version}. Intervals: 5th-95th percentile over bootstrap resamples of
the frames.</p>
<h2>Real and calibrated simulation</h2><img src="data:image/png;base64,{fans}" style="max-width:100%">
<h2>Fingerprint distance to the recording (lower is closer)</h2><table>{distances}</table>
<h2>Brightness profiles</h2><img src="data:image/png;base64,{profiles_figure(result)}" style="max-width:100%">
<p>Texture: {html.escape(texture)}.</p>
<h2>Fitted values</h2><table><tr><th>quantity</th><th>value</th><th>interval</th></tr>{''.join(rows)}</table>
<p>Residual gain: {gains}</p>
<p>Near-field band: {near_field}</p>
<h2>Grid ({html.escape(c.grid.bearing_source)}; ranges: {html.escape(c.grid.range_source)})</h2>
<table><tr><th>beams</th><th>range bins</th><th>window</th><th>fan (deg)</th><th>share</th></tr>{grids}</table>
<h2>Assumed, not measured</h2><ul>{notes}</ul></body></html>
"""
    path.write_text(page, encoding="utf-8")
    return path
