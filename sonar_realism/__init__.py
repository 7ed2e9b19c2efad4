"""sonar-realism: realistic forward-looking sonar from simulation, and why a simulation is not."""

from sonar_realism.errors import ConfigError, FormatError, FrameError, SonarRealismError, WireError
from sonar_realism.frames import SonarImage

__all__ = ["SonarImage", "SonarRealismError", "FrameError", "FormatError", "WireError", "ConfigError"]
__version__ = "0.1.0"
