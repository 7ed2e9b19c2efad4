"""Is a selected interference arcs that come and go, or a fixed band it absorbed?

The catalogue's interference is pulses from another source, out of sync with our pings: each ping's arcs land at
new ranges. A reflection inside the housing (or any fixed band) lights the same rows in every frame, and an
interference fitted at its strongest (many wide arcs per ping) can stand in for it in the statistics. So a row
that stands out of the rows around it in most real frames, more often than in the corrected sim's, is a band, not
interference: what the interference closed stays residual (and the gain pattern's band may name its place).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

# A row stands out when its mean is this far (a share of the level) above the running median of the rows around
# it; the window is wider than a housing band (a few per cent of the window) so the band cannot hide in it.
STANDOUT = 0.3
WINDOW_ROWS = 41
# The ring-down's rows (a fixed band the catalogue has) are not searched.
SKIP_SHARE = 0.1
# On the tuning sets, bands of 1-3 % of the window lit their rows in 78-100 % of the frames against 20-40 % for the
# scenes themselves and for every interference form (validation, tuning set, catalogue).
FIXED_EXCESS = 0.4


def fixed_row_share(images: np.ndarray) -> float:
    """The largest share of frames [n, n_ranges, n_beams] in which one row (beyond the first SKIP_SHARE) stands
    out of its neighbourhood."""
    rows = images.astype(np.float32).mean(axis=2)
    level = median_filter(rows, size=(1, WINDOW_ROWS), mode="nearest")
    lit = rows - level > STANDOUT * (level + 0.01)
    first = int(SKIP_SHARE * rows.shape[1])
    return float(lit[:, first:].mean(axis=0).max()) if rows.shape[1] > first else 0.0


@dataclass(frozen=True)
class ArcCheck:
    """The share of real frames lighting one fixed row and the corrected sim's; arcs that move are confirmed
    unless the real share exceeds the sim's by `needed`."""

    real_share: float
    sim_share: float
    needed: float = FIXED_EXCESS

    @property
    def confirmed(self) -> bool:
        return self.real_share - self.sim_share < self.needed

    def describe(self) -> str:
        return (f"arcs that move from ping to ping; one row stands out in {100 * self.real_share:.0f}% of the real "
                f"frames against {100 * self.sim_share:.0f}% of the corrected sim's (a fixed band from "
                f"{100 * self.needed:.0f} points more)")


def check_arcs(real_images: np.ndarray, sim_images: np.ndarray) -> ArcCheck:
    return ArcCheck(fixed_row_share(real_images), fixed_row_share(sim_images))
