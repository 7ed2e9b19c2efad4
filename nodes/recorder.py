"""recorder: writes every received frame losslessly (frames folder; NPZ or ROS 2 MCAP bag if `path` ends in
.npz or .mcap) and a contact-sheet PNG of fan views, then stops when the stream ends."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.runtime.node import Node
from sonar_realism.runtime.recording import Recording

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecorderParams:
    path: str = "recording"           # "{out}" is replaced with the launch run folder
    contact_sheet: str = ""           # PNG path; "" = <path>.contact_sheet.png beside the recording
    sheet_tiles: int = 16
    fan_width_px: int = 320

    def validate(self) -> None:
        if not self.path:
            raise ConfigError("recorder: path must not be empty")
        if self.sheet_tiles < 1 or self.fan_width_px < 16:
            raise ConfigError("recorder: sheet_tiles must be >= 1 and fan_width_px >= 16")


class RecorderNode(Node):
    PARAMS = RecorderParams
    INPUTS = {"frames": ("polar", "polar_samples", "mask")}
    BATCH_SIZE = 16

    def configure(self) -> None:
        p: RecorderParams = self.params
        path = Path(p.path)
        sheet = Path(p.contact_sheet) if p.contact_sheet else path.with_name(path.stem + ".contact_sheet.png")
        self.recording = Recording(path, sheet, sheet_tiles=p.sheet_tiles, fan_width_px=p.fan_width_px,
                                   resume=self.restarted)

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        self.recording.add_batch(frames)

    def finish(self) -> None:
        summary = self.recording.close()
        summary["already_written"] = self.recording.already_written  # sent again after a restart, skipped
        summary["status"] = self.status()
        Path(str(self.recording.path) + ".summary.json").write_text(json.dumps(summary, indent=2))
        log.info("recorder %s: %d frames -> %s", self.name, summary["frames"], summary["path"])


NODE = RecorderNode
