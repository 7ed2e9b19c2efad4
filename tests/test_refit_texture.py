"""scripts/refit_texture.py: a checkpoint's texture layer refitted with the current rule, its weights kept; with the
training run's seed, a learned texture's refit is that run's own texture step."""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np
import pytest
import torch

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames
from sonar_realism.models.cdfcvae import CDFCVAE, CDFCVAEConfig, PerceptualConfig, load_checkpoint, save_checkpoint
from sonar_realism.models.learned_texture import TextureFitConfig
from sonar_realism.models.train import TrainConfig, fit
from tests.repo_script import load_repo_script

refit = load_repo_script("scripts/refit_texture.py", "refit_texture_under_test")


def _frames(recording: str, seed: int) -> list[SonarImage]:
    rng = np.random.default_rng(seed)
    rows = np.arange(64)[:, None]
    return [SonarImage((rng.rayleigh(30, (64, 64)) + 80 * (rows > 20)).clip(0, 255).astype(np.uint8),
                       uniform_ranges(64, 10.0), uniform_azimuths(64, np.radians(120)), seq=i,
                       meta={"recording": recording}) for i in range(6)]


def test_refit_keeps_the_weights_switches_the_detail_and_refuses_a_recording_it_lacks(tmp_path, monkeypatch):
    cfg = CDFCVAEConfig(grid=(16, 16), widths=(4, 8, 8), latent_dim=4, bottleneck_hw=(2, 2), skips=1, dropout=0.0,
                        output_stride=2, upsample="resize_conv", texture="speckle")
    torch.manual_seed(0)
    source = save_checkpoint(CDFCVAE(cfg), tmp_path / "before.safetensors",
                             {"normalisation": "frame_max", "texture_mixed_from": ["a", "b"]})
    write_frames([*_frames("rec_a", 0), *_frames("rec_b", 1)], tmp_path / "real")
    out = tmp_path / "after.safetensors"
    monkeypatch.setattr(sys, "argv", ["refit_texture.py", "--checkpoint", str(source), "--real",
                                      str(tmp_path / "real"), "--recordings", "rec_a", "--detail", "input",
                                      "--out", str(out)])
    refit.main()
    before, _ = load_checkpoint(source)
    after, info = load_checkpoint(out)
    assert after.cfg.detail == "input" and after.texture.is_fitted and not before.texture.is_fitted
    assert info["texture_refit_from"] == "before.safetensors" and info["normalisation"] == "frame_max"
    assert "texture_mixed_from" not in info  # the old texture's provenance goes with it
    weights = {k: v for k, v in before.state_dict().items() if not k.startswith("texture.")}
    assert all(torch.equal(v, after.state_dict()[k]) for k, v in weights.items())
    monkeypatch.setattr(sys, "argv", ["refit_texture.py", "--checkpoint", str(source), "--real",
                                      str(tmp_path / "real"), "--recordings", "rec_z", "--out", str(out)])
    with pytest.raises(ConfigError, match="rec_z"):
        refit.main()


def test_a_learned_texture_refit_with_the_runs_seed_is_the_runs_own_texture_step(tmp_path, monkeypatch):
    """Not a second pass over the checkpoint's fitted generators: the refit starts the texture where `train` does."""
    write_frames(_frames("rec_a", 0), tmp_path / "real")
    write_frames(_frames("sim", 2)[:4], tmp_path / "sim")
    model = CDFCVAEConfig(grid=(16, 16), widths=(4, 8, 8), latent_dim=4, bottleneck_hw=(2, 2), skips=1, dropout=0.0,
                          output_stride=2, upsample="resize_conv", texture="learned", texture_generators=2)
    schedule = TextureFitConfig(steps=3, crop=32, batch=2, generator_lr=1e-2)
    cfg = TrainConfig(model=model, perceptual=PerceptualConfig(layers=("relu1_1",), layer_weights=(1.0,),
                                                               weights="random"),
                      batch_size=4, epochs1=1, epochs2=1, texture_fit=schedule, seed=3)
    assert fit(cfg, tmp_path / "real", tmp_path / "sim", tmp_path / "run", device="cpu", progress=False)["finished"]
    (tmp_path / "schedule.json").write_text(json.dumps(dataclasses.asdict(schedule)))
    trained = tmp_path / "run" / "model.safetensors"
    for seed, out in ((3, tmp_path / "same.safetensors"), (4, tmp_path / "other.safetensors")):
        monkeypatch.setattr(sys, "argv", ["refit_texture.py", "--checkpoint", str(trained), "--real",
                                          str(tmp_path / "real"), "--sim", str(tmp_path / "sim"), "--texture-fit",
                                          str(tmp_path / "schedule.json"), "--seed", str(seed), "--out", str(out)])
        refit.main()

    def texture(path):
        return {k: v for k, v in load_checkpoint(path)[0].state_dict().items() if k.startswith("texture.")}

    original, same = texture(trained), texture(tmp_path / "same.safetensors")
    other = texture(tmp_path / "other.safetensors")
    assert all(torch.equal(v, same[k]) for k, v in original.items())
    assert not all(torch.equal(v, other[k]) for k, v in original.items())


def test_the_texture_refit_on_several_simulated_folders_draws_on_their_frames_pooled(tmp_path, monkeypatch):
    """Repeated --sim: the folders' frames in the order given, as if they were one folder (a probe of a texture drawn
    on several simulators; docs/RESULTS.md, 2026-11-29)."""
    write_frames(_frames("rec_a", 0), tmp_path / "real")
    sims = {"calibrated": _frames("sim", 2)[:4],
            "other": [SonarImage(np.full((48, 40), 200 - 20 * i, np.uint8), uniform_ranges(48, 30.0),
                                 uniform_azimuths(40, np.radians(60)), seq=i) for i in range(4)]}
    for name, frames in sims.items():
        write_frames(frames, tmp_path / name)
    write_frames([*sims["calibrated"], *sims["other"]], tmp_path / "one_folder")
    model = CDFCVAEConfig(grid=(16, 16), widths=(4, 8, 8), latent_dim=4, bottleneck_hw=(2, 2), skips=1, dropout=0.0,
                          output_stride=2, upsample="resize_conv", texture="learned")
    torch.manual_seed(0)
    source = save_checkpoint(CDFCVAE(model), tmp_path / "before.safetensors", {"normalisation": "frame_max"})
    (tmp_path / "schedule.json").write_text(json.dumps(dataclasses.asdict(
        TextureFitConfig(steps=3, crop=32, batch=2, generator_lr=1e-2))))

    def refit_on(*folders: str) -> dict[str, torch.Tensor]:
        out = tmp_path / f"{'+'.join(folders)}.safetensors"
        monkeypatch.setattr(sys, "argv", ["refit_texture.py", "--checkpoint", str(source), "--real",
                                          str(tmp_path / "real"), *(arg for folder in folders
                                                                    for arg in ("--sim", str(tmp_path / folder))),
                                          "--texture-fit", str(tmp_path / "schedule.json"), "--out", str(out)])
        refit.main()
        return {k: v for k, v in load_checkpoint(out)[0].state_dict().items() if k.startswith("texture.")}

    pooled, together, alone = refit_on("calibrated", "other"), refit_on("one_folder"), refit_on("calibrated")
    assert all(torch.equal(v, together[k]) for k, v in pooled.items())
    assert not all(torch.equal(v, alone[k]) for k, v in pooled.items())
