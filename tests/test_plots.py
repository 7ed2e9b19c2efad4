"""Report figures (matplotlib) and the self-contained HTML page."""

import base64
import re

import cv2
import numpy as np
import pytest

from sonar_realism import plots
from sonar_realism.report_html import Figure, Row, Section, Table, Text, to_markdown, write_html

TAB_BLUE, TAB_ORANGE = (180, 119, 31), (14, 127, 255)  # matplotlib's first two colours, BGR


def count_colour(image, bgr, tolerance=30):
    return int((np.abs(image.astype(int) - bgr).sum(axis=2) < tolerance).sum())


def test_line_plot_draws_each_series(tmp_path):
    path = plots.line_plot({"train": ([0, 1, 2], [3.0, 2.0, 1.0]), "val": ([0, 1, 2], [3.5, 2.5, 2.0])},
                           tmp_path / "loss.png", "loss", "epoch", "L")
    image = cv2.imread(str(path))
    assert image.shape == (420, 720, 3)
    assert count_colour(image, TAB_BLUE) > 50 and count_colour(image, TAB_ORANGE) > 50


def test_log_plot_leaves_out_non_positive_values(tmp_path):
    path = plots.line_plot({"a": ([0, 1, 2], [0.0, 10.0, 100.0])}, tmp_path / "log.png", logy=True)
    assert cv2.imread(str(path)) is not None


def test_grouped_bars_put_before_and_after_side_by_side(tmp_path):
    path = plots.grouped_bar_plot(["speckle", "bearing_profile"], {"before": [2.0, 1.0], "after": [0.5, 0.25]},
                                  tmp_path / "g.png", "gap", "gap", reference=("gap before", 2.5))
    image = cv2.imread(str(path))
    blue, orange = count_colour(image, TAB_BLUE), count_colour(image, TAB_ORANGE)
    assert blue > 0 and orange > 0
    assert 2.5 < blue / orange < 6  # bar areas follow the values (4:1, less the legend patches)
    columns_blue = np.flatnonzero((np.abs(image.astype(int) - TAB_BLUE).sum(axis=2) < 30).sum(axis=0) > 20)
    columns_orange = np.flatnonzero((np.abs(image.astype(int) - TAB_ORANGE).sum(axis=2) < 30).sum(axis=0) > 20)
    assert columns_blue.min() < columns_orange.min()  # "before" left of "after" in each group


def test_image_grid_keeps_pixels_and_layout(tmp_path):
    images = [np.full((10, 20), v, np.uint8) for v in (0, 100, 200)] + [np.full((10, 20), 0.5, np.float32)]
    path = plots.image_grid(images, tmp_path / "grid.png", ncols=2, labels=list("abcd"))
    grid = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert grid.shape == (2 * (10 + 18 + 4), 2 * (20 + 4))
    assert abs(int(grid[18 + 5, 24 + 5]) - 100) <= 1
    assert abs(int(grid[32 + 18 + 5, 24 + 5]) - 127) <= 1


def test_heatmap_has_a_colour_bar_and_fans_are_fans(tmp_path):
    heat = cv2.imread(str(plots.heatmap(np.arange(12.0).reshape(3, 4), tmp_path / "h.png", "map",
                                        extent=(-60, 60, 0.5, 20), xlabel="bearing (deg)", ylabel="range (m)",
                                        colorbar_label="gap")))
    assert heat is not None and heat.shape[1] >= 320
    ranges, bearings = np.linspace(1, 10, 32), np.radians(np.linspace(-30, 30, 40))
    fan = cv2.imread(str(plots.fan_grid([(np.ones((32, 40)), ranges, bearings)], tmp_path / "f.png", ncols=1)))
    # Full-scale cells (inferno's pale yellow) widen from the apex up to the arc: drawn as a fan, not a rectangle.
    rows = np.flatnonzero(count_rows := (np.abs(fan.astype(int) - (164, 255, 252)).sum(axis=2) < 60).sum(axis=1))
    near, far = count_rows[rows.min() + int(0.8 * rows.size)], count_rows[rows.min() + int(0.2 * rows.size)]
    assert near < 0.5 * far


def test_html_page_is_self_contained_and_matches_the_markdown(tmp_path):
    png = plots.line_plot({"a": ([0, 1], [1.0, 2.0])}, tmp_path / "a.png", "a")
    page = [Section("Gap <b>", [Text("**bold** and `code`\n\nsecond <i>"), Table(["x", "y"], [[1, "a|b"]]),
                                Row([Figure(png, "left"), Figure(png, "right")])])]
    path = write_html(tmp_path / "report.html", "Title", page, subtitle="sub")
    text = path.read_text()
    assert "<strong>bold</strong>" in text and "<code>code</code>" in text and "&lt;b&gt;" in text
    assert "<i>" not in text  # user text is escaped
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(images) == 2 and base64.b64decode(images[0]) == png.read_bytes()
    markdown = to_markdown("Title", page)
    assert markdown.startswith("# Title") and "| 1 | a\\|b |" in markdown and "![left](a.png)" in markdown


def test_html_page_screenshot_in_headless_chromium(tmp_path):
    from sonar_realism.report_html import find_browser, screenshot

    browser = find_browser()
    if browser is None:
        pytest.skip("no headless Chromium found (apt-get install chromium, or set SONAR_REALISM_BROWSER)")
    ranges, bearings = np.linspace(1, 10, 32), np.radians(np.linspace(-60, 60, 40))
    fans = plots.fan_grid([(np.random.default_rng(0).random((32, 40)), ranges, bearings)] * 2, tmp_path / "f.png",
                          ncols=2, labels=["sim", "real"])
    page = write_html(tmp_path / "report.html", "Screenshot check", [Section("Fans", [Figure(fans, "two fans")])])
    shot = screenshot(page, tmp_path / "shot.png", browser=browser)
    image = cv2.imread(str(shot))
    assert image is not None and image.shape[0] > 300 and image.shape[1] > 600
    # The embedded figure was rendered: the inferno colours of the fans appear in the screenshot.
    assert (image[:, :, 2].astype(int) - image[:, :, 0].astype(int) > 80).sum() > 1000
