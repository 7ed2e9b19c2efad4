"""Sim-to-real gap diagnosis: how big the gap is, where it lies, which catalogued effect causes it, how far it
shrinks when the effects are added, and what residual no catalogued effect explains."""

from sonar_realism.diagnose.diagnosis import DiagnoseConfig, Diagnosis, diagnose

__all__ = ["DiagnoseConfig", "Diagnosis", "diagnose"]
