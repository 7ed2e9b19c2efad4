"""The translator node's logic: a batch of simulated frames in, n realistic samples per frame out, with
provenance (which input, which checkpoint, which seed) so that any output can be traced and reproduced."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, Protocol

from sonar_realism.frames import SonarImage


class SupportsTranslate(Protocol):
    def translate(self, frames: Sequence[SonarImage], n: int, temperature: float = 1.0,
                  seed: int | None = None) -> list[SonarImage]: ...


class TranslationStage:
    """Calls the translator on a batch and stamps every output with the input's seq/stamp/frame_id.

    The output keeps the input's `seq`: it names the ping along the whole pipeline (a viewer pairs simulated
    and translated frames by it) and it is what makes a lossless resend after a crash idempotent. So gaps
    downstream of a translator include the frames it dropped itself (its `dropped`/`stale` counters).

    With a `seed`, a batch is seeded with `seed + seq of its first frame`, so a replayed stream gives the
    same samples when it is batched the same way (batches depend on arrival timing under load).
    """

    def __init__(self, translator: SupportsTranslate, n: int, temperature: float = 1.0, seed: int | None = None,
                 checkpoint_sha256: str = "", node: str = "translator") -> None:
        self.translator = translator
        self.n = n
        self.temperature = temperature
        self.seed = seed
        self.checkpoint_sha256 = checkpoint_sha256
        self.node = node
        self.last_ms = 0.0

    def __call__(self, frames: Sequence[SonarImage]) -> list[SonarImage]:
        """One output per input frame. A [1, ranges, beams] input is the same image as [ranges, beams] and is
        translated; several samples per input raise FrameError (the node counts that frame as malformed)."""
        if not frames:
            return []
        frames = [f.sample(0) if f.intensity.ndim == 3 and f.n_samples == 1 else f for f in frames]
        batch_seed = None if self.seed is None else self.seed + frames[0].seq
        start = time.perf_counter()
        outputs = self.translator.translate(list(frames), self.n, self.temperature, batch_seed)
        self.last_ms = (time.perf_counter() - start) * 1000.0
        if len(outputs) != len(frames):
            raise RuntimeError(f"translator returned {len(outputs)} frames for {len(frames)} inputs")
        return [self._traced(source, out, batch_seed) for source, out in zip(frames, outputs, strict=True)]

    def _traced(self, source: SonarImage, output: SonarImage, batch_seed: int | None) -> SonarImage:
        carried = output.meta.get("provenance")
        provenance: dict[str, Any] = {
            **(carried if isinstance(carried, dict) else {}),  # what the translator itself recorded
            "node": self.node,
            "input_seq": source.seq,
            "input_stamp_ns": source.stamp_ns,
            "checkpoint_sha256": self.checkpoint_sha256,
            "n": self.n,
            "temperature": self.temperature,
            "seed": batch_seed,
        }
        meta = {**source.meta, **output.meta, "provenance": provenance}
        return output.replace(seq=source.seq, stamp_ns=source.stamp_ns, frame_id=source.frame_id, meta=meta)
