"""Sim-to-real gap diagnosis: how big the gap is, where it lies, which catalogued effect causes it (and when it
cannot tell), how far it shrinks when the effects are added, and what residual no catalogued effect explains."""

from sonar_realism.diagnose.config import DiagnoseConfig
from sonar_realism.diagnose.diagnosis import diagnose
from sonar_realism.diagnose.result import Diagnosis, load_diagnosis

__all__ = ["DiagnoseConfig", "Diagnosis", "diagnose", "load_diagnosis"]
