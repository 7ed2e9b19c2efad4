"""scripts/detection_goal.py: detector settings from the command line, and per-seed pairing against raw sim."""

import numpy as np
import pytest
from repo_script import load_repo_script

from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.detection import Box, DetectorConfig

goal = load_repo_script("scripts/detection_goal.py", "detection_goal_script")


def test_detector_settings_parse_as_json_and_reject_unknown_keys() -> None:
    config = goal.detector_config(["steps=7", "max_zoom=3", "dilations=[1, 2]"])
    assert (config.steps, config.max_zoom, config.dilations) == (7, 3.0, (1, 2))
    assert goal.detector_config([]) == DetectorConfig()
    with pytest.raises(ConfigError, match="unknown key.*zoom"):
        goal.detector_config(["zoom=3"])
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        goal.detector_config(["steps"])
    with pytest.raises(ConfigError, match="not JSON"):
        goal.detector_config(["steps=many"])


def test_the_same_training_set_and_seeds_pair_to_zero_difference_and_folds_cover_every_frame() -> None:
    rng = np.random.default_rng(0)
    images = (0.3 * rng.random((8, 32, 32))).astype(np.float32)
    boxes = [[Box(8.0, 8.0, 16.0, 20.0)] for _ in images]
    images[:, 8:16, 8:20] = 1.0
    frames = goal.LabelledFrames(images, boxes)
    config = DetectorConfig(grid=(32, 32), channels=8, steps=3, batch_size=2)
    everything = range(8)
    raw = goal.score("raw", [(frames, everything)], frames, config, [0, 1])
    again = goal.score("again", [(frames, everything)], frames, config, [0, 1], raw)
    assert again.ap_minus_raw_per_seed == (0.0, 0.0)
    folds = goal.score("folds", [(frames.part(4), range(0, 4)), (frames.part(0, 4), range(4, 8))], frames, config,
                       [0, 1], raw)
    assert folds.training_frames == 4 and len(folds.ap_minus_raw_per_seed) == 2
    assert 0.0 <= folds.ap_mean <= 1.0


def test_the_goal_line_says_whether_the_paired_difference_is_beyond_its_standard_error() -> None:
    def result(method: str, aps: tuple[float, ...], raw: tuple[float, ...]) -> goal.MethodResult:
        paired = tuple(a - b for a, b in zip(aps, raw, strict=True))
        return goal.MethodResult(method, 10, 10, aps, aps, aps, 1.0, paired)

    raw = (0.17, 0.03, 0.01, 0.14, 0.01)
    noisy = result("noisy", (0.09, 0.05, 0.06, 0.04, 0.02), raw)  # the session's first five seeds: -0.021
    clear = result("clear", tuple(a + 0.05 for a in raw), raw)
    lines = goal.goal_lines([result(goal.RAW, raw, raw), noisy, clear])
    assert "NOT met" in lines[0] and "within one standard error" in lines[0]
    assert "met" in lines[1] and "beyond one standard error" in lines[1] and "+0.050" in lines[1]
