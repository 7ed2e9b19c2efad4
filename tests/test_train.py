"""Two-cycle cDFCVAE training on tiny data: loss goes down, early stopping, resume, CLI config."""

import argparse
import dataclasses
import json

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from sonar_realism.config import from_dict
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames
from sonar_realism.models import train as train_module
from sonar_realism.models.cdfcvae import CDFCVAEConfig, PerceptualConfig, load_checkpoint
from sonar_realism.models.datasets import load_grid_frames, split_by_recording
from sonar_realism.models.learned_texture import TextureFitConfig
from sonar_realism.models.train import EarlyStopping, TrainConfig, add_arguments, config_from_args, fit

TINY_MODEL = CDFCVAEConfig(grid=(16, 16), widths=(4, 8), latent_dim=4, bottleneck_hw=(2, 2), skips=1, dropout=0.0)
TINY_LOSS = PerceptualConfig(layers=("relu1_1",), layer_weights=(1.0,), weights="random")


def _frames(n, recording, seed, shape=(24, 20)):
    rng = np.random.default_rng(seed)
    for i in range(n):
        image = (rng.rayleigh(40, shape) + 60 * (np.arange(shape[0])[:, None] > shape[0] // 2)).clip(0, 255)
        yield SonarImage(image.astype(np.uint8), uniform_ranges(shape[0], 20.0),
                         uniform_azimuths(shape[1], np.radians(130)), seq=i, meta={"recording": recording})


@pytest.fixture
def data(tmp_path):
    real = tmp_path / "real"
    write_frames([*_frames(10, "rec_a", 0), *_frames(4, "rec_b", 1)], real)
    sim = tmp_path / "sim"
    write_frames(_frames(8, "sim", 2, shape=(16, 16)), sim)
    return real, sim


def _cfg(**kw):
    return TrainConfig(model=TINY_MODEL, perceptual=TINY_LOSS, batch_size=4, learning_rate=3e-3, **kw)


def test_real_frames_are_split_by_recording(data):
    real, _ = data
    frames = load_grid_frames(real, (16, 16))
    assert frames.images.shape == (14, 16, 16) and frames.images.max() == pytest.approx(1.0)
    train, val, how = split_by_recording(frames)
    assert {frames.recordings[i] for i in val} == {"rec_b"} and len(train) == 10 and "rec_b" in how
    train, val, _ = split_by_recording(frames, ["rec_a"])
    assert len(val) == 10
    with pytest.raises(ConfigError, match="rec_z"):
        split_by_recording(frames, ["rec_z"])


def test_loss_decreases_and_both_cycles_write_a_checkpoint(data, tmp_path):
    real, sim = data
    out = tmp_path / "run"
    result = fit(_cfg(epochs1=6, epochs2=2, patience=10), real, sim, out, device="cpu", progress=False)
    assert result["finished"]
    history = json.loads((out / "state.json").read_text())["history"]
    cycle1 = [row["train_loss"] for row in history["1"]]
    assert len(cycle1) == 6 and cycle1[-1] < 0.9 * cycle1[0]
    assert len(history["2"]) == 2
    record = json.loads((out / "early_stopping.json").read_text())
    assert record["n_real"] == [10, 4] and record["cycles"]["2"]["epochs_done"] == 2
    model, info = load_checkpoint(out / "model.safetensors")
    assert info["trained_cycles"] == 2 and model.cfg == TINY_MODEL
    # Cycle 2 trains only the simulation encoder: the decoder is cycle 1's.
    cycle1_weights = load_file(str(out / "cycle1.safetensors"))
    final = load_file(str(out / "model.safetensors"))
    assert all((final[k] == cycle1_weights[k]).all() for k in final if k.startswith("decoder."))
    assert any((final[k] != cycle1_weights[k]).any() for k in final if k.startswith("encoder_sim."))
    assert (out / "loss_curves.png").stat().st_size > 1000


def test_resume_gives_the_same_result_as_an_uninterrupted_run(data, tmp_path):
    real, sim = data
    cfg = _cfg(epochs1=3, epochs2=2, patience=10)
    fit(cfg, real, sim, tmp_path / "straight", device="cpu", progress=False)
    first = fit(cfg, real, sim, tmp_path / "split", device="cpu", progress=False, max_epochs_now=2)
    assert not first["finished"] and not (tmp_path / "split" / "model.safetensors").exists()
    second = fit(cfg, real, sim, tmp_path / "split", device="cpu", progress=False, resume=True, max_epochs_now=2)
    assert not second["finished"]  # stopped inside cycle 2 this time
    assert fit(cfg, real, sim, tmp_path / "split", device="cpu", progress=False, resume=True)["finished"]
    a = load_file(str(tmp_path / "straight" / "model.safetensors"))
    b = load_file(str(tmp_path / "split" / "model.safetensors"))
    assert a.keys() == b.keys() and all((a[k] == b[k]).all() for k in a)
    history_a = json.loads((tmp_path / "straight" / "state.json").read_text())["history"]
    history_b = json.loads((tmp_path / "split" / "state.json").read_text())["history"]
    assert history_a == history_b


def test_resume_refuses_a_different_configuration(data, tmp_path):
    real, sim = data
    fit(_cfg(epochs1=1, epochs2=0), real, None, tmp_path / "run", device="cpu", progress=False)
    with pytest.raises(ConfigError, match="different configuration"):
        fit(_cfg(epochs1=2, epochs2=0, seed=5), real, None, tmp_path / "run", device="cpu", progress=False,
            resume=True)
    with pytest.raises(ConfigError, match="no training state"):
        fit(_cfg(), real, None, tmp_path / "empty", device="cpu", progress=False, resume=True)


def test_early_stopping_record():
    record = EarlyStopping(patience=2, min_improvement=0.01)
    assert record.update(10.0) and record.update(9.0)
    assert not record.update(8.95)  # less than 1 % better: not progress
    assert not record.stopped
    assert not record.update(9.5)
    assert record.stopped and record.best_epoch == 2 and record.best_loss == 9.0
    assert "2 epochs" in record.stopped_reason


def test_early_stopping_ends_a_cycle_and_keeps_the_best_epoch(data, tmp_path):
    real, _ = data
    # A learning rate this large diverges after the first epochs, so the validation loss stops improving.
    cfg = TrainConfig(model=TINY_MODEL, perceptual=TINY_LOSS, batch_size=4, learning_rate=5.0, epochs1=30,
                      epochs2=0, patience=2)
    result = fit(cfg, real, None, tmp_path / "run", device="cpu", progress=False)
    record = result["cycles"]["1"]
    assert record["epochs_done"] < 30 and "no improvement" in record["stopped_reason"]
    assert record["epochs_done"] == record["best_epoch"] + 2


def test_cli_flags_override_the_json_config_and_unknown_keys_are_rejected(tmp_path):
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    config = tmp_path / "cfg.json"
    config.write_text(json.dumps({"epochs1": 7, "batch_size": 3, "model": {"latent_dim": 12}}))
    args = parser.parse_args(["--real", "r", "--out", "o", "--config", str(config), "--batch-size", "5",
                              "--grid", "64x32"])
    cfg = config_from_args(args)
    assert (cfg.epochs1, cfg.batch_size, cfg.model.latent_dim, cfg.model.grid) == (7, 5, 12, (64, 32))
    assert cfg.real_recordings == ()
    args.recordings = "rec_a, rec_b"
    assert config_from_args(args).real_recordings == ("rec_a", "rec_b")
    config.write_text(json.dumps({"learning_rat": 1e-3}))
    with pytest.raises(ConfigError, match="learning_rat"):
        config_from_args(args)
    with pytest.raises(ConfigError, match="grid"):
        from_dict(TrainConfig, {"model": {"grid": [100, 128]}})


def test_texture_model_trains_on_the_chosen_recordings_and_fits_speckle_after_cycle_1(tmp_path):
    real, sim = tmp_path / "real", tmp_path / "sim"
    write_frames([*_frames(6, "rec_a", 0, shape=(64, 64)), *_frames(4, "rec_b", 1, shape=(64, 64))], real)
    write_frames(_frames(6, "sim", 2, shape=(64, 64)), sim)
    model = CDFCVAEConfig(grid=(16, 16), widths=(4, 8, 8), latent_dim=4, bottleneck_hw=(2, 2), skips=1,
                          dropout=0.0, output_stride=2, upsample="resize_conv", texture="speckle")
    cfg = TrainConfig(model=model, perceptual=TINY_LOSS, batch_size=4, epochs1=1, epochs2=1,
                      real_recordings=("rec_a",))
    out = tmp_path / "run"
    assert fit(cfg, real, sim, out, device="cpu", progress=False)["finished"]
    record = json.loads((out / "early_stopping.json").read_text())
    assert record["n_real"] == [5, 1] and "single recording" in record["real_split"]
    trained, _ = load_checkpoint(out / "model.safetensors")
    assert trained.texture.is_fitted
    # Rayleigh speckle around the decoder's mean: the fitted ratios spread well beyond a flat image's.
    quantiles = trained.texture.ratio_quantiles.numpy()
    assert np.median(quantiles[:, -20] - quantiles[:, 20]) > 0.5
    with pytest.raises(ConfigError, match="rec_z"):
        fit(TrainConfig(model=model, perceptual=TINY_LOSS, epochs1=1, real_recordings=("rec_z",)), real, None,
            tmp_path / "run2", device="cpu", progress=False)


def test_cycle1_checkpoint_retargets_to_another_simulator_training_only_the_sim_encoder(data, tmp_path):
    real, sim = data
    first = tmp_path / "first"
    fit(_cfg(epochs1=2, epochs2=1), real, sim, first, device="cpu", progress=False)
    cycle1 = load_file(str(first / "cycle1.safetensors"))
    out = tmp_path / "retarget"
    result = fit(_cfg(epochs1=2, epochs2=2), real, sim, out, device="cpu", progress=False,
                 cycle1=first / "cycle1.safetensors")
    assert result["finished"]
    history = json.loads((out / "state.json").read_text())["history"]
    assert history["1"] == [] and len(history["2"]) == 2
    retargeted = load_file(str(out / "model.safetensors"))
    decoder = [k for k in cycle1 if k.startswith("decoder.")]
    assert decoder and all(np.array_equal(cycle1[k].float().numpy(), retargeted[k].float().numpy()) for k in decoder)
    assert any(not np.array_equal(cycle1[k].float().numpy(), retargeted[k].float().numpy())
               for k in cycle1 if k.startswith("encoder_sim."))
    with pytest.raises(ConfigError, match="model configuration"):
        fit(dataclasses.replace(_cfg(epochs1=1, epochs2=1), model=dataclasses.replace(TINY_MODEL, latent_dim=6)),
            real, sim, tmp_path / "other", device="cpu", progress=False, cycle1=first / "cycle1.safetensors")


def test_a_learned_texture_is_fitted_after_cycle_2_on_the_simulated_frames_and_after_cycle_1_without_them(
        tmp_path, monkeypatch):
    real, sim = tmp_path / "real", tmp_path / "sim"
    write_frames(_frames(6, "rec_a", 0, shape=(64, 64)), real)
    write_frames(_frames(4, "sim", 2, shape=(64, 64)), sim)
    model = CDFCVAEConfig(grid=(16, 16), widths=(4, 8, 8), latent_dim=4, bottleneck_hw=(2, 2), skips=1,
                          dropout=0.0, output_stride=2, upsample="resize_conv", texture="learned")
    cfg = TrainConfig(model=model, perceptual=TINY_LOSS, batch_size=4, epochs1=1, epochs2=1,
                      texture_fit=TextureFitConfig(steps=3, crop=32, batch=2, generator_lr=1e-2))
    fitted_on = []
    real_fit = train_module.fit_model_texture

    def recording_the_weights(model, *args, **kwargs):
        fitted_on.append({k: v.clone() for k, v in model.state_dict().items() if k.startswith("decoder.")})
        return real_fit(model, *args, **kwargs)

    monkeypatch.setattr(train_module, "fit_model_texture", recording_the_weights)
    assert fit(cfg, real, sim, tmp_path / "run", device="cpu", progress=False)["finished"]
    # fitted on the decoder as the half-precision checkpoint holds it, which is what `translate` decodes with
    assert len(fitted_on) == 1 and all(torch.equal(v, v.half().float()) for v in fitted_on[0].values())
    # the sim encoder is not trained at cycle 1's end, so the texture waits for cycle 2 to know what it draws on
    assert not load_checkpoint(tmp_path / "run" / "cycle1.safetensors")[0].texture.is_fitted
    fitted = load_checkpoint(tmp_path / "run" / "model.safetensors")[0]
    assert fitted.texture.is_fitted
    # the generators were trained, not left as cycle 2 ended with them (its optimiser froze the whole model once)
    before = load_file(tmp_path / "run" / "state.safetensors")
    generators = {k: v for k, v in fitted.state_dict().items() if k.startswith("texture.generators.")}
    assert max((v.float() - before[f"best.{k}"].float()).abs().max().item() for k, v in generators.items()) > 1e-2
    assert fit(cfg, real, None, tmp_path / "real_only", device="cpu", progress=False)["finished"]
    assert load_checkpoint(tmp_path / "real_only" / "cycle1.safetensors")[0].texture.is_fitted


def test_the_shipped_training_configs_parse_and_say_their_texture():
    """The recipes' configs (scripts/train_sensor.sh's CONFIG) are valid TrainConfigs: a typo would only surface an
    hour into training otherwise."""
    from pathlib import Path

    scripts = Path(__file__).resolve().parents[1] / "scripts"
    textures = {path.stem: from_dict(TrainConfig, json.loads(path.read_text()), path.name).model.texture
                for path in scripts.glob("cdfcvae_*.json")}
    assert textures == {"cdfcvae_default": "learned", "cdfcvae_speckle": "speckle", "cdfcvae_paper": "none"}
