"""Geometry and scene candidates of the diagnosis (see base.py). Importing the package registers every term: one
file per term."""

from sonar_realism.diagnose.scene_terms import mounting, seabed  # noqa: F401  (imported for their registrations)
from sonar_realism.diagnose.scene_terms.base import (
    SCENE_TERMS,
    Kind,
    SceneStart,
    SceneTerm,
    apply_scene_terms,
    kind_of,
    scene_term_starts,
)

__all__ = ["SCENE_TERMS", "Kind", "SceneStart", "SceneTerm", "apply_scene_terms", "kind_of", "scene_term_starts"]
