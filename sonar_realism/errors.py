"""Typed errors. Every error names where the problem is (file, field) so a user can act on it."""

from __future__ import annotations


class SonarRealismError(Exception):
    """Base class of every error this library raises on purpose."""


class FrameError(SonarRealismError, ValueError):
    """A SonarImage was built from inconsistent or invalid fields."""


class FormatError(SonarRealismError, ValueError):
    """A recording or file could not be decoded.

    `source` names the file (or stream), `field` the header field or record that is wrong.
    """

    def __init__(self, source: str, field: str, message: str, offset: int | None = None) -> None:
        self.source = str(source)
        self.field = field
        self.offset = offset
        where = f" at byte {offset}" if offset is not None else ""
        super().__init__(f"{self.source}{where}: {field}: {message}")


class UnsupportedFormatError(FormatError):
    """A well-formed record uses a feature this library does not decode (e.g. 24-bit samples)."""


class WireError(SonarRealismError, ValueError):
    """A ZeroMQ message does not follow docs/wire-format.md.

    `topic` names the message's topic (None when the topic part itself is unreadable), `field` the part or
    header field that is wrong (the names of docs/wire-format.md, "Errors").
    """

    def __init__(self, field: str, message: str, topic: str | None = None) -> None:
        self.field = field
        self.topic = topic
        where = f"topic {topic!r}: " if topic is not None else ""
        super().__init__(f"{where}{field}: {message}")


class ConfigError(SonarRealismError, ValueError):
    """A configuration (dataclass, launch file, CLI option) is invalid."""
