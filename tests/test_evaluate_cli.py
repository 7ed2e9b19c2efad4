"""`sonar-realism evaluate` end to end on tiny data: a tiny CycleGAN, two sim categories, the report files; and
how a --model argument names its column."""

import json

import numpy as np
import pytest

from sonar_realism.cli import main
from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.cli import _translator_from_spec
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames
from sonar_realism.models.translate import Translator
from sonar_realism.sim.masks import write_mask


def frames(n: int, seed: int, speckle: bool, scene: str | None = None) -> list[SonarImage]:
    """Clean boxes on a seabed ramp ("sim") or the same with Rayleigh speckle ("real"), 48 x 32 polar frames."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        image = np.repeat(np.linspace(0.2, 0.4, 48, dtype=np.float32)[:, None], 32, axis=1)
        r, c = rng.integers(8, 36), rng.integers(4, 24)
        image[r:r + 6, c:c + 6] = 1.0
        image[r + 6:, c:c + 6] = 0.02
        if speckle:
            image = image * rng.rayleigh(0.8, image.shape).astype(np.float32)
        image = (np.clip(image / image.max(), 0, 1) * 255).astype(np.uint8)
        meta = {"scene": scene} if scene else {}
        out.append(SonarImage(image, uniform_ranges(48, 20.0), uniform_azimuths(32, 2.2), seq=i, meta=meta))
    return out


def test_evaluate_writes_table_metrics_and_figures(tmp_path):
    write_frames(frames(16, 1, speckle=True), tmp_path / "real")
    write_frames(frames(8, 5, speckle=True), tmp_path / "other_real")  # another "recording" of the sensor
    organic = frames(8, 2, speckle=False)
    write_frames(organic, tmp_path / "organic")  # category from the folder name
    for index, frame in enumerate(organic):  # object masks beside the frames, as `sonar-realism simulate` writes
        write_mask(tmp_path / "organic", index, (frame.intensity == 255).astype(np.uint8))
    write_frames(frames(8, 3, speckle=False, scene="constructed"), tmp_path / "sim2")  # from frame meta
    write_frames(frames(8, 4, speckle=False), tmp_path / "train_sim")
    (tmp_path / "tiny.json").write_text(json.dumps({"ngf": 4, "ndf": 4, "n_blocks": 1}))
    assert main(["train", "--model", "cyclegan", "--real", str(tmp_path / "real"), "--sim", str(tmp_path / "train_sim"),
                 "--out", str(tmp_path / "cg"), "--grid", "32x32", "--epochs", "1", "--batch-size", "4",
                 "--config", str(tmp_path / "tiny.json")]) == 0

    out = tmp_path / "eval"
    assert main(["evaluate", "--real", str(tmp_path / "real"), "--sim", str(tmp_path / "organic"),
                 "--sim", str(tmp_path / "sim2"), "--model", f"cyclegan={tmp_path / 'cg'}", "--out", str(out),
                 "--grid", "32x32", "--n", "2", "--cnn-epochs", "8", "--yardstick", str(tmp_path / "other_real")]) == 0

    results = json.loads((out / "results.json").read_text())
    assert results["inputs"]["command"].startswith(f"sonar-realism evaluate --real {tmp_path / 'real'} --sim ")
    assert set(results["table"]) == {"organic", "constructed", "all"}
    assert set(results["table"]["organic"]) == {"raw sim", "cyclegan"}
    assert results["data"] == {"n_real": 16, "n_real_cnn": 8, "n_real_reference": 8, "n_real_other": 8, "n_sim_cnn": 8,
                               "n_sim_scored": 8, "sim_scored_per_category": {"constructed": 4, "organic": 4}}
    table = results["table"]["all"]
    for cell in table.values():
        assert 0.0 <= cell["ci_low"] <= cell["mean"] <= cell["ci_high"] <= 1.0
    # Speckled "real" and clean "sim" are easy to tell apart: held-out real scores above raw simulation.
    assert table["real (held out)"]["mean"] > table["raw sim"]["mean"]
    other = table["real (other recording)"]
    assert other["n"] == 8 and other["mean"] > table["raw sim"]["mean"]
    assert "real (other recording)" not in results["table"]["organic"]
    cyclegan = results["methods"]["cyclegan"]
    assert cyclegan["diversity"]["relative"] == 0.0  # deterministic translator: n identical samples
    assert results["methods"]["raw sim"]["c2st"]["accuracy"] >= 0.5
    assert results["methods"]["raw sim"]["edge_ssim"] == 1.0  # raw sim is its own input
    assert results["methods"]["raw sim"]["mask_iou"] > 0.8  # the masks of the organic folder were read
    report = (out / "report.md").read_text()
    assert "Table I" in report and "paper 0.114–0.212" in report and "| cyclegan |" in report
    for name in results["figures"].values():
        assert (out / name).stat().st_size > 1000
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == len(results["figures"]) and "paper 0.114–0.212" in page


def test_evaluate_names_a_missing_folder(tmp_path, capsys):
    code = main(["evaluate", "--real", str(tmp_path / "nowhere"), "--sim", str(tmp_path), "--out", str(tmp_path / "o")])
    assert code == 2
    assert "nowhere" in capsys.readouterr().err


def test_evaluate_names_a_model_column_by_its_kind_unless_told(tmp_path):
    from test_nodes import tiny_checkpoint
    from test_translate import tiny_cyclegan

    checkpoint = tiny_checkpoint(tmp_path)
    assert _translator_from_spec(str(checkpoint), "cpu")[0] == "cdfcvae"
    assert _translator_from_spec(str(tiny_cyclegan(tmp_path / "cg")), "cpu")[0] == "cyclegan"
    name, translator, path = _translator_from_spec(f"mine={checkpoint}", "cpu")
    assert (name, path) == ("mine", str(checkpoint)) and isinstance(translator, Translator)
    with pytest.raises(ConfigError, match="no such checkpoint"):
        _translator_from_spec(str(tmp_path / "absent.safetensors"), "cpu")
