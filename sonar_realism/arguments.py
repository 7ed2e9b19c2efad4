"""What every subcommand checks of its arguments before any work: numbers in their range, and output paths that
can be written. A calibration or a diagnosis runs for minutes; it must not end in a traceback because `--report`
names a folder that cannot be made, nor write into the recording it reads."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from sonar_realism.errors import ConfigError


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number >= 0 (seeds: numpy's generators take no negative seed)."""
    value = _whole(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {value}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a whole number >= 1 (counts and limits, where 0 would mean nothing or, silently, all)."""
    value = _whole(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be 1 or more, got {value}")
    return value


def _whole(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None


def json_object(path: str | Path, flag: str, what: str) -> dict:
    """The JSON object in file `path` (ConfigError naming `flag` if unreadable or not an object); `what` says
    what its keys are, for the message."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{flag} {path}: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{flag} {path}: expected a JSON object of {what}, got {type(data).__name__}")
    return data


def output_folder(path: str | Path, flag: str) -> Path:
    """Folder `path` made if missing and checked writable (ConfigError naming `flag` if not)."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{flag} {folder}: exists and is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{flag} {folder}: cannot make the folder ({exc.strerror or exc})") from exc
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"{flag} {folder}: the folder is not writable")
    return folder


def output_file(path: str | Path, flag: str) -> Path:
    """File `path` checked writable: not a folder, its folder made if missing and writable (ConfigError naming
    `flag` if not). Nothing is written to it."""
    file = Path(path)
    if file.is_dir():
        raise ConfigError(f"{flag} {file}: is a folder; name the file to write")
    output_folder(file.parent, f"{flag} {file}: its folder")
    if file.exists() and not os.access(file, os.W_OK):
        raise ConfigError(f"{flag} {file}: exists and is not writable")
    return file


def not_the_input(out: str | Path, inp: str | Path, out_flag: str, in_flag: str) -> None:
    """ConfigError if writing `out` would replace the recording `inp` being read (the same file or folder)."""
    if Path(out).resolve() == Path(inp).resolve():
        raise ConfigError(f"{out_flag} {out} is the {in_flag} recording: writing there would replace the frames "
                          f"being read; choose another {out_flag}")
