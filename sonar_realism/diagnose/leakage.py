"""Is a selected beam_sidelobes leakage across beams, or a floor it absorbed?

Sidelobes and cross-talk move power along a constant-range row: a row that holds a bright return lifts its dark
beams with it, and the rows around it (without that return) stay as they were. A noise floor lifts dark cells
whatever the row holds, and a yaw smear spreads a return over a few beams only, not to the row's dark beams;
fitted at their strongest (a -10 dB skirt, a -39 dB cross-talk pedestal) the catalogue's sidelobes can still stand
in for either in the statistics. So the check compares the real frames' row-coupled lift (`row_coupled_lift`) with the
lift the fitted effect itself puts on the sim's frames: a fitted form that predicts a clear lift the real frames do
not show is not what is in them, and the sidelobes give way to their step's runner-up (diagnose/which.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POWER_FLOOR = 1e-4  # full-scale power (amplitude 0.01): below it a cell's level is the rendering's zero, not a floor
DARK_QUANTILE = 0.25  # a row's dark beams: its lower quartile of power
PEAK_SHARE = 0.05  # the rows whose peak stands out most from the rows around it
NEAR_ROWS, FAR_ROWS = 3, 10  # a row's neighbourhood: rows 3 to 10 away (a range blur's spread stays inside 3)
# On the tuning forms and the catalogue (default scene, 40 frames a side; docs/RESULTS.md), a fitted sidelobe that
# matched its true effect predicted 0.02-0.18 and the real frames showed 0.04-0.90; sidelobes fitted in place of a
# noise floor or a yaw smear predicted 0.61-0.65 where the real frames showed -0.01-0.03.
LEAST_PREDICTED = 0.15
SHOWN_SHARE = 0.5


def row_coupled_lift(images: np.ndarray) -> float:
    """How far the dark beams of rows with a standing-out peak rise above the rows around them, beyond the
    average row: images [n, n_ranges, n_beams] (amplitude), in log power."""
    power = images.astype(np.float64) ** 2
    peak = _against_neighbours(np.log(power.max(axis=2) + POWER_FLOOR))
    dark = _against_neighbours(np.log(np.quantile(power, DARK_QUANTILE, axis=2) + POWER_FLOOR))
    standing_out = peak > np.quantile(peak, 1.0 - PEAK_SHARE)
    return float(dark[standing_out].mean() - dark.mean()) if standing_out.any() else 0.0


def _against_neighbours(rows: np.ndarray) -> np.ndarray:
    """[n, n_ranges]: each row less the median of the rows NEAR_ROWS to FAR_ROWS away from it in its frame."""
    n_ranges = rows.shape[1]
    padded = np.pad(rows, ((0, 0), (FAR_ROWS, FAR_ROWS)), mode="edge")
    offsets = [o for o in range(-FAR_ROWS, FAR_ROWS + 1) if abs(o) >= NEAR_ROWS]
    around = np.stack([padded[:, FAR_ROWS + o:FAR_ROWS + o + n_ranges] for o in offsets])
    return rows - np.median(around, axis=0)


@dataclass(frozen=True)
class LeakageCheck:
    """The row-coupled lift of the real frames (`real`), of the sim's corrected by the other selected effects
    (`sim`) and of those with the fitted sidelobes too (`with_effect`). Unconfirmed when the fitted effect predicts
    at least LEAST_PREDICTED more than the sim's and the real frames show less than SHOWN_SHARE of that."""

    real: float
    sim: float
    with_effect: float

    @property
    def predicted(self) -> float:
        return self.with_effect - self.sim

    @property
    def shown(self) -> float:
        return self.real - self.sim

    @property
    def confirmed(self) -> bool:
        return self.predicted < LEAST_PREDICTED or self.shown >= SHOWN_SHARE * self.predicted

    def describe(self) -> str:
        return (f"leakage along the row: the fitted sidelobes lift the dark beams of rows with a bright return by "
                f"{self.predicted:.2f} (log power) over the rows around them, the real frames by {self.shown:.2f}")


def check_leakage(real_images: np.ndarray, sim_images: np.ndarray, with_effect_images: np.ndarray) -> LeakageCheck:
    return LeakageCheck(row_coupled_lift(real_images), row_coupled_lift(sim_images),
                        row_coupled_lift(with_effect_images))
