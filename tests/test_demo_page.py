"""The demo's page: inputs paired with their translations by seq, a real frame beside them, one HTML file."""

import re

import numpy as np

from sonar_realism.demo_page import DemoPage
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames


def frame(seq, samples=0, max_range=15.0):
    shape = (samples, 40, 32) if samples else (40, 32)
    return SonarImage(np.random.default_rng(seq).random(shape).astype(np.float32), uniform_ranges(40, max_range),
                      uniform_azimuths(32, 2.2), seq=seq)


def test_page_pairs_inputs_with_their_samples_and_shows_a_real_frame(tmp_path):
    write_frames([frame(0, max_range=30.0)], tmp_path / "real")
    page = DemoPage(rows=2, real=tmp_path / "real")
    for seq in range(3):
        page.add_simulated(frame(seq))
    page.add_translated(frame(1, samples=3))
    page.add_translated(frame(2, samples=3))  # its input was not kept (rows=2): not shown
    page.add_translated(frame(0, samples=3))
    text = page.write(tmp_path / "demo.html").read_text()
    assert "3 simulated, 3 translated" in text and str(tmp_path / "real") in text
    assert len(re.findall("data:image/png;base64,", text)) == 1
    assert (tmp_path / "demo_fans.png").stat().st_size > 10_000


def test_page_without_translations_or_real_data_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("SONAR_REALISM_DATA", str(tmp_path / "no_data"))
    page = DemoPage(rows=2)
    page.add_simulated(frame(0))
    text = page.write(tmp_path / "demo.html").read_text()
    assert "No translated frame arrived" in text and "SONAR_REALISM_DATA" in text
