"""translator: simulated frames in, n cDFCVAE samples per frame out ([n, ranges, beams]; 8-bit
samples from a checkpoint with a texture layer, docs/nodes.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from sonar_realism.errors import ConfigError, FrameError
from sonar_realism.frames import SonarImage
from sonar_realism.runtime.node import Node
from sonar_realism.runtime.translation import TranslationStage


@dataclass(frozen=True)
class TranslatorParams:
    checkpoint: str = ""      # "" = the shipped checkpoint (sonar_realism.models.translate.DEFAULT_CHECKPOINT)
    n: int = 4                # samples per input frame
    temperature: float = 1.0  # latent scale: 0 = the mean image, 1 = the trained spread
    seed: int = -1            # -1 = fresh randomness; >= 0 = reproducible (seed + seq of the batch's first frame)
    batch: int = 4            # most frames per model call (a backlog is translated in batches)
    device: str = "auto"      # "auto", "cpu", "cuda", "cuda:1", ...
    # largest input frame, in pixels (the model works on about 310 bytes of memory per input pixel at its peak):
    # a bigger one is refused as malformed instead of taking the machine's memory
    max_pixels: int = 16_777_216

    def validate(self) -> None:
        if self.n < 1 or self.batch < 1 or self.max_pixels < 1:
            raise ConfigError(f"translator: n ({self.n}), batch ({self.batch}) and max_pixels ({self.max_pixels}) "
                              f"must be >= 1")
        if not 0 <= self.temperature < math.inf:
            raise ConfigError(f"translator: temperature must be a number >= 0, got {self.temperature}")
        if self.checkpoint and not Path(self.checkpoint).is_file():
            raise ConfigError(f"translator: checkpoint {self.checkpoint}: no such file")


class TranslatorNode(Node):
    PARAMS = TranslatorParams
    INPUTS = {"frames": ("polar",)}
    OUTPUTS = {"frames": "polar_samples"}

    def configure(self) -> None:
        from sonar_realism.models.translate import DEFAULT_CHECKPOINT, Translator  # torch: only when this node runs

        p: TranslatorParams = self.params
        checkpoint = p.checkpoint or str(DEFAULT_CHECKPOINT)
        translator = Translator.from_checkpoint(checkpoint, device=p.device)
        self.stage = TranslationStage(translator, n=p.n, temperature=p.temperature,
                                      seed=None if p.seed < 0 else p.seed,
                                      checkpoint_sha256=translator.checkpoint_sha256, node=self.name)
        self.batch_size = p.batch

    def process(self, input_name: str, frames: list[SonarImage]) -> None:
        for frame in frames:
            if frame.intensity.size > self.params.max_pixels:
                raise FrameError(f"intensity: frame seq {frame.seq} has {frame.intensity.size} pixels, more than "
                                 f"the translator's max_pixels ({self.params.max_pixels})")
        outputs = self.stage(frames)
        self.record_inference(self.stage.last_ms, len(frames))
        for frame in outputs:
            self.publish("frames", frame)


NODE = TranslatorNode
