"""demo_page: the simulated frames and their translations in, one HTML page at the end of the stream (per row
the simulated input, its n samples and a real frame, as fans; sonar_realism.demo_page)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from sonar_realism.demo_page import DemoPage
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.runtime.node import Node

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoPageParams:
    path: str = "demo.html"  # "{out}" is replaced with the launch run folder
    rows: int = 4            # inputs shown (the first ones that got translated)
    real: str = ""           # a recording for the real column; "" = the real Oculus set when the data folder has it

    def validate(self) -> None:
        if not self.path or self.rows < 1:
            raise ConfigError("demo_page: path must not be empty and rows must be >= 1")


class DemoPageNode(Node):
    PARAMS = DemoPageParams
    INPUTS = {"simulated": ("polar",), "translated": ("polar_samples",)}

    def configure(self) -> None:
        p: DemoPageParams = self.params
        self.page = DemoPage(p.rows, p.real or None)

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        add = self.page.add_simulated if input_name == "simulated" else self.page.add_translated
        for frame in frames:
            add(frame)

    def finish(self) -> None:
        path = self.page.write(self.params.path)
        log.info("demo_page %s: %s", self.name, path)


NODE = DemoPageNode
