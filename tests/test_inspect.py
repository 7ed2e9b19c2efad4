"""`sonar-realism inspect`: per-frame metadata, summary and what the reader skipped."""

import json
import subprocess
import sys

import cv2
import numpy as np

from sonar_realism import SonarImage
from sonar_realism.cli import main
from sonar_realism.frames import uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames


def recording(tmp_path):
    frames = [SonarImage(np.full((40, 16), i, np.uint8), uniform_ranges(40, 10.0), uniform_azimuths(16, 1.2),
                         stamp_ns=1_754_412_000_000_000_000 + i * 100_000_000, seq=20 * i) for i in range(5)]
    write_frames(frames, tmp_path / "rec")
    return tmp_path / "rec"


def test_table_lists_frames_and_summary(tmp_path, capsys):
    assert main(["inspect", str(recording(tmp_path))]) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.strip().startswith(("0", "1", "2", "3", "4"))]
    assert len(lines) == 5 and "seq 80" in lines[4] and "40x16" in lines[0] and "2025-08-05T16:40:00" in lines[0]
    assert "frames-folder, 5 frame(s)" in out and "rate_hz: 10.0" in out


def test_json_output_reports_skipped_files_and_assumed_geometry(tmp_path, capsys):
    folder = tmp_path / "pngs"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), np.full((30, 20), 9, np.uint8))
    (folder / "README.txt").write_text("hello")
    assert main(["inspect", str(folder), "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["kind"] == "folder"
    assert document["summary"]["frames"] == 3 and document["summary"]["geometry_assumed"] == 3
    assert document["report"]["skipped"] == {"not a frame file (.txt)": 1}
    assert [f["seq"] for f in document["frames"]] == [0, 1, 2]
    assert document["frames"][0]["shape"] == [30, 20] and document["frames"][0]["max_range_m"] == 29.5


def test_max_frames_and_bad_input_exit_codes(tmp_path, capsys):
    assert main(["inspect", str(recording(tmp_path)), "--json", "--max-frames", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["summary"]["frames"] == 2
    assert main(["inspect", str(tmp_path / "missing")]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "junk.bin").write_bytes(b"\x00" * 100)
    assert main(["inspect", str(tmp_path / "junk.bin")]) == 2
    assert "magic: unrecognised content" in capsys.readouterr().err


def test_command_line_entry_point_runs_as_a_subprocess(tmp_path):
    result = subprocess.run([sys.executable, "-m", "sonar_realism.cli", "inspect", str(recording(tmp_path)),
                             "--json", "--quiet"], capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert document["summary"]["frames"] == 5 and "frames" not in document
    assert document["summary"]["seq"] == [0, 80]
