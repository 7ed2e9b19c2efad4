from dataclasses import dataclass, field
from typing import Literal

import pytest

from sonar_realism.config import from_dict, to_dict
from sonar_realism.errors import ConfigError


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    layers: tuple[str, ...] = ("a",)
    mode: Literal["fast", "slow"] = "fast"
    inner: Inner = field(default_factory=Inner)

    def validate(self) -> None:
        if self.inner.gain < 0:
            raise ConfigError("inner.gain: must be >= 0")


def test_round_trip():
    cfg = from_dict(Outer, {"name": "y", "layers": ["a", "b"], "inner": {"gain": 2}})
    assert cfg == Outer("y", ("a", "b"), "fast", Inner(2.0))
    assert from_dict(Outer, to_dict(cfg)) == cfg


@pytest.mark.parametrize(
    "data, message",
    [
        ({"nmae": "y"}, "unknown key"),
        ({"inner": {"gian": 1}}, "Outer.inner: unknown key"),
        ({"mode": "medium"}, "not one of"),
        ({"inner": {"gain": "high"}}, "expected a number"),
        ({"inner": {"gain": -1}}, "must be >= 0"),
    ],
)
def test_rejects_bad_configs(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(Outer, data)


@dataclass(frozen=True)
class Record:
    version: int
    effects: dict
    note: str = ""


def test_missing_required_keys_are_named():
    with pytest.raises(ConfigError, match=r"CALIB: missing key\(s\) effects$"):
        from_dict(Record, {"version": 1}, where="CALIB")
    assert from_dict(Record, {"version": 1, "effects": {}}).note == ""
