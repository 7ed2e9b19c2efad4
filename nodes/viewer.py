"""viewer: a live view in Foxglove (sonar_realism.live_view). The simulated and the translated frames become fan
images on /sonar/simulated and /sonar/translated, and this node's status (frames in, drops, seq gaps per
second) goes to /viewer/status, served on ws://localhost:PORT. Wire its inputs with policy "latest": a
viewer never slows the pipeline down."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.live_view import LiveView
from sonar_realism.runtime.node import Node

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ViewerParams:
    host: str = "127.0.0.1"     # localhost only
    port: int = 8765            # Foxglove: Open connection -> ws://localhost:8765
    width_px: int = 480         # fan image width per sample
    max_samples: int = 4        # samples of a translated frame shown side by side
    status_period_s: float = 1.0

    def validate(self) -> None:
        if not 0 <= self.port < 65536 or self.width_px < 16 or self.max_samples < 1 or self.status_period_s <= 0:
            raise ConfigError("viewer: port in [0, 65535], width_px >= 16, max_samples >= 1, status_period_s > 0")


class ViewerNode(Node):
    PARAMS = ViewerParams
    INPUTS = {"simulated": ("polar",), "translated": ("polar_samples",)}

    def configure(self) -> None:
        p: ViewerParams = self.params
        self.view = LiveView(p.host, p.port, p.width_px, p.max_samples)
        self._last_status = 0.0
        log.info("viewer %s: Foxglove -> ws://localhost:%d", self.name, self.view.port)

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        for frame in frames:
            self.view.show(f"/sonar/{input_name}", frame)
        now = time.monotonic()
        if now - self._last_status >= self.params.status_period_s:
            self._last_status = now
            self.view.status(self.status())

    def finish(self) -> None:
        self.view.status(self.status())
        self.view.close()


NODE = ViewerNode
