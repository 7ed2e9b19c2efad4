import os

from sonar_realism import cli
from sonar_realism.data import DATA_ENV, OCULUS_FIT_RECORDING, data_root, oculus_recording_files


def test_data_folder_comes_from_the_flag_then_the_environment_then_beside_the_checkout(tmp_path, monkeypatch):
    monkeypatch.delenv(DATA_ENV, raising=False)
    assert data_root().parts[-2:] == ("shared", "data")
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "env"))
    assert data_root() == tmp_path / "env"
    assert data_root(tmp_path / "flag") == tmp_path / "flag"


def test_cli_data_flag_points_every_reader_at_that_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "not_this_one"))  # also restores the variable after the test
    images = tmp_path / "real" / "oculus_polar_seabed" / "dataset" / "train" / "images"
    images.mkdir(parents=True)
    (images / f"{OCULUS_FIT_RECORDING}_frame_00020.png").write_bytes(b"")
    # "inspect" is the subcommand even though the flag's value comes first and looks like a word
    assert cli.build_parser(["--data", str(tmp_path), "inspect"])[1] == "inspect"
    assert cli.main(["--data", str(tmp_path), "inspect", str(images)]) == 0
    assert os.environ[DATA_ENV] == str(tmp_path)
    assert [p.name for p in oculus_recording_files(OCULUS_FIT_RECORDING)] == [f"{OCULUS_FIT_RECORDING}_frame_00020.png"]
    assert "not a frame file" in capsys.readouterr().out  # the empty PNG is skipped with its reason, no crash
