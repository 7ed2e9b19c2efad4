"""Inputs the coverage-guided fuzzers (scripts/fuzz_wire.py, scripts/fuzz_oculus.py) found to reach new code,
replayed on every run: the decoders must give a result or their own typed error, nothing else."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sonar_realism.errors import FormatError, WireError
from sonar_realism.io.oculus import decode_ping, read_oculus
from sonar_realism.wire import FRAME_TYPE, decode_message

FOLDER = Path(__file__).parent / "data" / "fuzz"


def load(name: str, key: str) -> list:
    path = FOLDER / name
    return json.loads(path.read_text())[key] if path.exists() else []


@pytest.mark.parametrize("index, parts", list(enumerate(load("wire_messages.json", "messages"))),
                         ids=lambda value: str(value) if isinstance(value, int) else "")
def test_fuzzed_wire_messages_decode_or_raise_wire_error(index, parts):
    parts = [bytes.fromhex(part) for part in parts]
    try:
        message = decode_message(parts)
    except WireError as error:
        assert error.field
        return
    if message.kind == FRAME_TYPE:
        assert message.body.intensity.nbytes == len(parts[2])


@pytest.mark.parametrize("index, data", list(enumerate(load("oculus_inputs.json", "inputs"))),
                         ids=lambda value: str(value) if isinstance(value, int) else "")
def test_fuzzed_oculus_inputs_decode_or_raise_format_error(index, data, tmp_path):
    data = bytes.fromhex(data)
    try:
        assert decode_ping(data).intensity.ndim == 2
    except FormatError:
        pass
    path = tmp_path / "input.bin"
    path.write_bytes(data)
    try:
        assert all(frame.intensity.ndim == 2 for frame in read_oculus(path))
    except FormatError:
        pass
