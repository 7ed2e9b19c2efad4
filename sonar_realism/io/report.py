"""What a reader skipped or could not decode, so that nothing is dropped silently."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field


@dataclass
class ReadReport:
    """Filled in by a reader as it goes. `skipped` counts records by reason (e.g. "msg_id 0xff",
    "item type 500", "garbage bytes"); `problems` keeps a short human-readable line per corrupt record."""

    source: str = ""
    frames: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    problems: list[str] = field(default_factory=list)
    max_problems: int = 100

    def skip(self, reason: str, count: int = 1) -> None:
        self.skipped[reason] += count

    def problem(self, message: str) -> None:
        self.skipped["corrupt record"] += 1
        if len(self.problems) < self.max_problems:
            self.problems.append(message)

    def as_dict(self) -> dict[str, object]:
        return {"source": self.source, "frames": self.frames, "skipped": dict(self.skipped),
                "problems": list(self.problems)}
