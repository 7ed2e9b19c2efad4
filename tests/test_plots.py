import cv2
import numpy as np

from sonar_realism import plots


def test_line_plot_draws_each_series(tmp_path):
    path = plots.line_plot({"train": ([0, 1, 2], [3.0, 2.0, 1.0]), "val": ([0, 1, 2], [3.5, 2.5, 2.0])},
                           tmp_path / "loss.png", "loss", "epoch", "L")
    image = cv2.imread(str(path))
    assert image.shape == (420, 720, 3)
    # both series colours appear (tab10 blue and orange, BGR)
    assert (np.abs(image.astype(int) - (180, 119, 31)).sum(axis=2) < 30).sum() > 50
    assert (np.abs(image.astype(int) - (14, 127, 255)).sum(axis=2) < 30).sum() > 50


def test_log_plot_ignores_non_positive(tmp_path):
    path = plots.line_plot({"a": ([0, 1, 2], [0.0, 10.0, 100.0])}, tmp_path / "log.png", logy=True)
    assert cv2.imread(str(path)) is not None


def test_image_grid_layout(tmp_path):
    images = [np.full((10, 20), v, np.uint8) for v in (0, 100, 200)] + [np.full((10, 20), 0.5, np.float32)]
    path = plots.image_grid(images, tmp_path / "grid.png", ncols=2, labels=list("abcd"))
    grid = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert grid.shape == (2 * (10 + 18 + 4), 2 * (20 + 4))
    assert grid[18 + 5, 24 + 5] == 100
    assert grid[32 + 18 + 5, 24 + 5] == 127


def test_heatmap_and_bars(tmp_path):
    heat = cv2.imread(str(plots.heatmap(np.arange(12.0).reshape(3, 4), tmp_path / "h.png", "map")))
    assert heat is not None and heat.shape[1] >= 320
    bars = cv2.imread(str(plots.bar_plot(["x", "y"], [1.0, 2.0], tmp_path / "b.png", errors=[0.1, 0.2])))
    assert bars is not None
