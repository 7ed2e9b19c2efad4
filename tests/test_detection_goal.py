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
