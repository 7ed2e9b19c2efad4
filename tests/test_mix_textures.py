"""scripts/mix_textures.py: learned textures fitted apart on one translator, joined into one mixture."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest
import torch

from sonar_realism.errors import ConfigError
from sonar_realism.models.cdfcvae import CDFCVAE, CDFCVAEConfig, load_checkpoint, save_checkpoint
from sonar_realism.models.learned_texture import TextureFitConfig
from tests.repo_script import load_repo_script

mix = load_repo_script("scripts/mix_textures.py", "mix_textures_under_test")
CFG = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8, 16), latent_dim=8, bottleneck_hw=(2, 2), skips=2,
                    texture="learned")


def _fitted(model: CDFCVAE, seed: int) -> CDFCVAE:
    rng = np.random.default_rng(seed)
    images = [rng.random((32, 32)).astype(np.float32) for _ in range(2)]
    model.texture.fit(images, [np.full((32, 32), 0.5, np.float32)] * 2, seed=seed,
                      schedule=TextureFitConfig(steps=2, crop=32, batch=2))
    return model


def test_textures_of_one_translator_join_in_order_and_others_are_refused(tmp_path, monkeypatch):
    torch.manual_seed(0)
    base = CDFCVAE(CFG)
    paths = []
    for seed in (0, 1):
        twin = CDFCVAE(CFG)
        twin.load_state_dict(base.state_dict())
        paths.append(str(save_checkpoint(_fitted(twin, seed), tmp_path / f"s{seed}.safetensors",
                                         {"normalisation": "frame_max", "texture_refit_from": "x"})))
    out = tmp_path / "mixed.safetensors"
    monkeypatch.setattr(sys, "argv", ["mix_textures.py", "--checkpoint", paths[0], "--checkpoint", paths[1],
                                      "--out", str(out)])
    mix.main()
    joined, info = load_checkpoint(out)
    assert joined.cfg.texture_generators == 2 and info["normalisation"] == "frame_max"
    assert "texture_refit_from" not in info and len(info["texture_mixed_from"]) == 2
    for k, path in enumerate(paths):
        source, _ = load_checkpoint(path)
        for key, value in source.texture.generators[0].state_dict().items():
            assert torch.equal(joined.texture.generators[k].state_dict()[key], value)
    assert all(torch.equal(value, joined.state_dict()[key]) for key, value in base.state_dict().items()
               if not key.startswith("texture."))

    other = _fitted(CDFCVAE(CFG), 2)  # another translator's weights
    stranger = save_checkpoint(other, tmp_path / "other.safetensors")
    with pytest.raises(ConfigError, match="other.safetensors: encoder"):
        mix.mixed([paths[0], str(stranger)])
    speckled = save_checkpoint(CDFCVAE(dataclasses.replace(CFG, texture="speckle")), tmp_path / "speckle.safetensors")
    with pytest.raises(ConfigError, match="only learned textures mix"):
        mix.mixed([str(speckled), paths[0]])
