"""The conformance vectors (conformance/README.md): every valid message decodes to its expected.json, every
invalid one is rejected naming the expected field, and the files are exactly what make_vectors.py writes."""

from __future__ import annotations

import json
import runpy
from pathlib import Path

import numpy as np
import pytest

from sonar_realism.errors import WireError
from sonar_realism.wire import FRAME_TYPE, decode_message

FOLDER = Path(__file__).resolve().parents[1] / "conformance"
VALID = sorted((FOLDER / "valid").iterdir())
INVALID = sorted((FOLDER / "invalid").iterdir())


def parts_of(folder: Path) -> list[bytes]:
    count = len(list(folder.glob("part*.bin")))
    return [(folder / f"part{number}.bin").read_bytes() for number in range(1, count + 1)]


@pytest.mark.parametrize("folder", VALID, ids=lambda p: p.name)
def test_valid_vectors_decode_to_their_expected_values(folder):
    expected = json.loads((folder / "expected.json").read_text())
    message = decode_message(parts_of(folder))
    assert (message.kind, message.topic, message.sent_ns) == (expected["kind"], expected["topic"],
                                                              expected["sent_ns"])
    if message.kind != FRAME_TYPE:
        assert message.body == expected["status"]
        return
    frame = message.body
    assert (frame.seq, frame.stamp_ns, frame.frame_id, frame.intensity_scale) == (
        expected["seq"], expected["stamp_ns"], expected["frame_id"], expected["intensity_scale"])
    assert frame.intensity.dtype.str == expected["dtype"] and list(frame.intensity.shape) == expected["shape"]
    np.testing.assert_array_equal(frame.intensity, np.array(expected["intensity"], dtype=expected["dtype"]))
    np.testing.assert_allclose(frame.ranges_m, expected["ranges_m"], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(frame.azimuths_rad, expected["azimuths_rad"])
    assert frame.meta == expected["meta"]


@pytest.mark.parametrize("folder", INVALID, ids=lambda p: p.name)
def test_invalid_vectors_are_rejected_naming_the_expected_field(folder):
    expected = json.loads((folder / "expected.json").read_text())
    with pytest.raises(WireError) as caught:
        decode_message(parts_of(folder))
    assert (caught.value.field, caught.value.topic) == (expected["error_field"], expected["topic"])


def test_the_files_are_what_the_generator_writes(tmp_path):
    generator = runpy.run_path(str(FOLDER / "make_vectors.py"))
    generator["write"](tmp_path)
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(FOLDER) for p in FOLDER.rglob("*") if p.is_file() and p.parent != FOLDER)
    assert written == committed
    assert all((tmp_path / p).read_bytes() == (FOLDER / p).read_bytes() for p in written)
