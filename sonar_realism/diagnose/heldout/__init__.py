"""The held-out half of the diagnosis' validation (see base.py). Importing the package registers every
implementation: one file per effect family, plus the un-catalogued effects."""

from sonar_realism.diagnose.heldout import (  # noqa: F401  (imported for their registrations)
    beam_sidelobes,
    elevation_spread,
    gamma_quantization,
    interference,
    motion_blur,
    multipath,
    range_blur,
    ring_down,
    speckle,
    tvg_noise,
    uncatalogued,
)
from sonar_realism.diagnose.heldout.base import (
    BLIND,
    IMPLEMENTATIONS,
    REGISTRIES,
    TUNING,
    UNCATALOGUED,
    Implementation,
    Param,
    Place,
    apply_held_out,
    find_implementation,
)

__all__ = ["BLIND", "IMPLEMENTATIONS", "REGISTRIES", "TUNING", "UNCATALOGUED", "Implementation", "Param", "Place",
           "apply_held_out", "find_implementation"]
