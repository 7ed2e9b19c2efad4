"""file_replay: any recording `read_frames` reads, on its recorded clock (times `speed`) or as fast as
consumers take it, optionally looped and cut to [start_s, stop_s] of recording time."""

from __future__ import annotations

from dataclasses import dataclass

from sonar_realism.errors import ConfigError
from sonar_realism.runtime.node import TimedSourceNode
from sonar_realism.runtime.sources import ReplaySource


@dataclass(frozen=True)
class FileReplayParams:
    path: str = ""
    speed: float = 1.0      # 1 = recorded timing, 2 = twice as fast, 0 = as fast as possible
    loop: bool = False
    start_s: float = 0.0    # offsets in recording time from the first frame
    stop_s: float = 0.0     # 0 = to the end
    restamp: bool = False   # stamp frames with the publish time (originals kept in meta)

    def validate(self) -> None:
        if not self.path:
            raise ConfigError("file_replay: path is required")
        if self.speed < 0 or self.start_s < 0 or self.stop_s < 0:
            raise ConfigError("file_replay: speed, start_s and stop_s must be >= 0")


class FileReplayNode(TimedSourceNode):
    PARAMS = FileReplayParams
    OUTPUTS = {"frames": "polar"}

    def configure(self) -> None:
        p: FileReplayParams = self.params
        self.source = ReplaySource(p.path, p.speed, p.loop, p.start_s, p.stop_s, p.restamp)


NODE = FileReplayNode
