"""Shared test fixtures: the real data sets, skipped with the reason when the data folder is absent."""

from pathlib import Path

import pytest

from sonar_realism.data import DATA_ENV, real_aris_dir, real_oculus_dir


def _require(path: Path) -> Path:
    if not path.is_dir():
        pytest.skip(f"real data not found at {path} (set {DATA_ENV} or put shared/data beside the checkout)")
    return path


@pytest.fixture
def real_oculus() -> Path:
    """The real Oculus polar set's dataset/ folder."""
    return _require(real_oculus_dir())


@pytest.fixture
def real_aris() -> Path:
    """The real ARIS water-tank set's folder (Images/, Masks/, BoxAnnotations/)."""
    return _require(real_aris_dir())
