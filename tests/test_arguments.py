"""The checks every subcommand makes of its arguments before any work, through the `sonar-realism` command."""

import json
import os

import numpy as np
import pytest

from sonar_realism.arguments import output_file, output_folder
from sonar_realism.cli import main
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.io import load_recording, write_frames


def _frames(n: int, shape=(40, 32), value: int | None = None) -> list[SonarImage]:
    rng = np.random.default_rng(0)
    azimuths = np.radians(np.linspace(-30.0, 30.0, shape[1]))
    return [SonarImage(np.full(shape, value, np.uint8) if value is not None
                       else rng.integers(0, 255, shape, dtype=np.uint8), uniform_ranges(shape[0], 10.0), azimuths,
                       seq=i, meta={"source": f"frame{i:03d}"}) for i in range(n)]


@pytest.mark.parametrize("command", [["simulate", "--n", "1"], ["diagnose", "--sim", "a", "--real", "b"],
                                     ["calibrate", "--real", "a"], ["translate", "--in", "a"],
                                     ["evaluate", "--real", "a"], ["train", "--real", "a"]])
def test_a_negative_seed_is_refused_by_the_parser(command, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main([*command, "--out", str(tmp_path / "out"), "--seed", "-1"])
    assert stop.value.code == 2
    assert "--seed: must be 0 or more, got -1" in capsys.readouterr().err


def test_output_paths_are_checked_before_any_work(tmp_path):
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    with pytest.raises(ConfigError, match="--out .*exists and is not a folder"):
        output_folder(a_file, "--out")
    with pytest.raises(ConfigError, match="--out .*cannot make the folder"):
        output_folder(a_file / "below", "--out")
    with pytest.raises(ConfigError, match="--report .*is a folder"):
        output_file(tmp_path, "--report")
    assert output_file(tmp_path / "new" / "report.html", "--report").parent.is_dir()
    if os.geteuid() != 0:  # root may write anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(ConfigError, match="not writable"):
            output_folder(locked, "--out")


def test_calibrate_stops_on_an_unwritable_report_before_it_reads_the_recording(tmp_path, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    code = main(["calibrate", "--real", str(tmp_path / "missing"), "--out", str(tmp_path / "CALIB.json"),
                 "--report", str(blocker / "report.html")])
    assert code == 2
    err = capsys.readouterr().err
    assert "--report" in err and "Traceback" not in err
    assert not (tmp_path / "CALIB.json").exists()


def test_a_data_set_split_into_subfolders_is_read_folder_by_folder(tmp_path):
    write_frames(_frames(3), tmp_path / "set" / "train")
    write_frames(_frames(2), tmp_path / "set" / "val")
    (tmp_path / "set" / "labels").mkdir()
    (tmp_path / "set" / "labels" / "a.txt").write_text("0 0.5 0.5 0.1 0.1\n")
    assert len(load_recording(tmp_path / "set")) == 5
    assert len(load_recording(tmp_path / "set", limit=2)) == 2


def test_diagnose_refuses_a_config_that_is_not_an_object(tmp_path, capsys):
    write_frames(_frames(8), tmp_path / "frames")
    (tmp_path / "config.json").write_text(json.dumps([]))
    code = main(["diagnose", "--sim", str(tmp_path / "frames"), "--real", str(tmp_path / "frames"),
                 "--out", str(tmp_path / "out"), "--config", str(tmp_path / "config.json")])
    assert code == 2
    assert "expected a JSON object of DiagnoseConfig fields, got list" in capsys.readouterr().err


def test_calibrate_refuses_blank_recordings_and_tiny_frames(tmp_path):
    from sonar_realism.sim.calibrate import CalibrateConfig, prepare_frames

    with pytest.raises(ConfigError, match="only 0 of 8 frame"):
        prepare_frames(_frames(8, value=0), CalibrateConfig())
    with pytest.raises(ConfigError, match="1 ranges x 1 beams"):
        prepare_frames(_frames(8, shape=(1, 1)), CalibrateConfig())


def test_an_operating_system_refusal_is_a_message_not_a_traceback(tmp_path, capsys):
    write_frames(_frames(2), tmp_path / "frames")
    code = main(["inspect", str(tmp_path / "frames" / "frames.jsonl" / "x")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err


@pytest.mark.parametrize("field, value, message", [
    ("effect_bootstrap", -1, "effect_bootstrap must be 0 or more, got -1"),
    ("default_fov_deg", 720.0, "default_fov_deg must be in 1..179"),
    ("learned_steps", 0, "learned_steps must be 1 or more, got 0")])
def test_a_calibration_setting_out_of_range_is_named(field, value, message):
    from sonar_realism.sim.calibrate import CalibrateConfig

    with pytest.raises(ConfigError, match=message):
        CalibrateConfig(**{field: value}).validate()


def test_cyclegan_only_flags_and_an_empty_sim_are_refused_for_the_cdfcvae(tmp_path, capsys):
    write_frames(_frames(4), tmp_path / "real")
    for extra, message in ((["--crop", "64"], "--crop: for --model cyclegan only"),
                           (["--epochs", "3"], "--epochs: for --model cyclegan only"),
                           (["--sim", ""], "--sim: empty")):
        code = main(["train", "--real", str(tmp_path / "real"), "--out", str(tmp_path / "run"), *extra])
        assert code == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_evaluate_names_the_one_setting_out_of_range(tmp_path, capsys):
    code = main(["evaluate", "--real", str(tmp_path / "none"), "--out", str(tmp_path / "out"), "--n", "0"])
    assert code == 2
    assert "n_samples must be 1 or more, got 0" in capsys.readouterr().err


def test_a_cdfcvae_run_without_cycle_1_says_so(tmp_path, capsys):
    write_frames(_frames(6), tmp_path / "real")
    main(["train", "--real", str(tmp_path / "real"), "--out", str(tmp_path / "run"), "--epochs1", "0",
          "--grid", "32x32", "--device", "cpu"])
    assert "epochs1 is 0 and no --cycle1 is given" in capsys.readouterr().err
