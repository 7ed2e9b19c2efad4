"""scripts/calibration_parts.py: a calibration with named parts taken from another, loaded and validated."""

from __future__ import annotations

import json

from repo_script import load_repo_script

from sonar_realism.sim.calibration import SHIPPED_CALIBRATIONS

parts = load_repo_script("scripts/calibration_parts.py", "calibration_parts_under_test")


def test_parts_come_from_the_donor_and_the_rest_stays_the_base() -> None:
    base = json.loads(SHIPPED_CALIBRATIONS["oculus"].read_text(encoding="utf-8"))
    donor = json.loads(SHIPPED_CALIBRATIONS["aris"].read_text(encoding="utf-8"))
    merged = parts.with_parts(base, donor, ["effects.speckle", "seabed"])
    assert merged["effects"]["speckle"] == donor["effects"]["speckle"] != base["effects"]["speckle"]
    assert merged["seabed"] == donor["seabed"] != base["seabed"]
    assert {k: v for k, v in merged["effects"].items() if k != "speckle"} == \
        {k: v for k, v in base["effects"].items() if k != "speckle"}
    assert merged["grid"] == base["grid"] and base["seabed"] != donor["seabed"]  # the base itself is not changed
    calibration = parts.load_merged(merged)
    assert calibration.seabed.patch_scale_m.value == donor["seabed"]["patch_scale_m"]["value"]
    assert calibration.grid.modes == parts.load_merged(base).grid.modes
