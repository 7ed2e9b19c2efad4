"""CycleGAN baseline: shapes, a training step that lowers the loss, the train CLI with resume, the translator."""

import json

import numpy as np
import pytest
import torch

from sonar_realism.cli import main
from sonar_realism.errors import FormatError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import write_frames
from sonar_realism.models.cyclegan import (
    CycleGAN,
    CycleGANConfig,
    CycleGANTranslator,
    ImagePool,
    PatchDiscriminator,
    ResnetGenerator,
    is_cyclegan_checkpoint,
)
from sonar_realism.models.train_cyclegan import lr_factor

TINY = CycleGANConfig(ngf=4, ndf=4, n_blocks=1)


def frames(n: int, seed: int, speckle: bool, shape: tuple[int, int] = (40, 24)) -> list[SonarImage]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        image = np.full(shape, 0.3, np.float32)
        r, c = rng.integers(5, shape[0] - 10), rng.integers(3, shape[1] - 8)
        image[r:r + 5, c:c + 5] = 1.0
        if speckle:
            image *= rng.rayleigh(0.8, shape).astype(np.float32)
        image = (np.clip(image / image.max(), 0, 1) * 255).astype(np.uint8)
        out.append(SonarImage(image, uniform_ranges(shape[0], 20.0), uniform_azimuths(shape[1], 2.2), seq=i))
    return out


def test_shapes_of_generator_and_patch_discriminator():
    x = torch.rand(2, 1, 64, 48) * 2 - 1
    y = ResnetGenerator(ngf=8, n_blocks=2)(x)
    assert y.shape == x.shape and y.abs().max() <= 1.0
    # 70x70 PatchGAN: three stride-2 and two stride-1 4x4 convs -> (H/8 - 2) x (W/8 - 2) logits.
    assert PatchDiscriminator(ndf=8)(x).shape == (2, 1, 6, 4)
    full = ResnetGenerator()  # stock size: 9 blocks, 64 filters, ~11.37 M parameters for one channel
    assert 11.3e6 < sum(p.numel() for p in full.parameters()) < 11.4e6


def test_one_generator_step_lowers_the_generator_loss():
    torch.manual_seed(0)
    model = CycleGAN(CycleGANConfig(ngf=8, ndf=8, n_blocks=2))
    a, b = torch.rand(2, 1, 32, 32) * 2 - 1, torch.rand(2, 1, 32, 32) * 2 - 1
    optimizer = torch.optim.Adam(list(model.g_ab.parameters()) + list(model.g_ba.parameters()), lr=2e-4,
                                 betas=(0.5, 0.999))
    before, _, _ = model.generator_loss(a, b)
    optimizer.zero_grad()
    before.backward()
    optimizer.step()
    after, terms, (fake_a, fake_b) = model.generator_loss(a, b)
    assert after.item() < before.item()
    assert set(terms) == {"gan", "cycle", "identity"} and fake_a.shape == a.shape
    assert model.discriminator_loss(a, b, fake_a, fake_b).item() > 0


def test_image_pool_returns_fresh_images_until_full_then_mixes_in_old_ones():
    pool = ImagePool(3, seed=0)
    first = torch.zeros(3, 1, 4, 4)
    assert torch.equal(pool.query(first), first)
    mixed = pool.query(torch.ones(20, 1, 4, 4))
    served_old = int((mixed.flatten(1).sum(1) == 0).sum())
    assert 0 < served_old <= 3  # at most the three stored zeros can come back
    assert torch.equal(ImagePool(0).query(first), first)


def test_learning_rate_is_constant_then_decays_linearly_to_zero():
    factors = [lr_factor(e, 10, 0.5) for e in range(10)]
    assert factors[:5] == [1.0] * 5
    assert all(x > y for x, y in zip(factors[4:], factors[5:], strict=False)) and 0 < factors[-1] < 0.2


def test_train_cli_resume_and_translator(tmp_path):
    write_frames(frames(6, 0, speckle=False), tmp_path / "sim")
    write_frames(frames(6, 1, speckle=True), tmp_path / "real")
    (tmp_path / "tiny.json").write_text(json.dumps({"ngf": 4, "ndf": 4, "n_blocks": 1, "pool_size": 4}))
    run = tmp_path / "run"
    common = ["train", "--model", "cyclegan", "--real", str(tmp_path / "real"), "--sim", str(tmp_path / "sim"),
              "--out", str(run), "--grid", "32x32", "--batch-size", "2", "--config", str(tmp_path / "tiny.json")]
    assert main([*common, "--epochs", "1"]) == 0
    meta = json.loads((run / "cyclegan.json").read_text())
    assert meta["model"] == "cyclegan" and meta["epoch"] == 1 and meta["config"]["ngf"] == 4
    assert is_cyclegan_checkpoint(run) and is_cyclegan_checkpoint(run / "cyclegan.safetensors")

    assert main([*common, "--epochs", "2", "--resume"]) == 0
    meta = json.loads((run / "cyclegan.json").read_text())
    assert meta["epoch"] == 2 and [h["epoch"] for h in meta["history"]] == [1, 2]

    translator = CycleGANTranslator.from_checkpoint(run, device="cpu")
    inputs = frames(2, 7, speckle=False, shape=(50, 30))
    outputs = translator.translate(inputs, n=3)
    assert len(outputs) == 2
    for source, out in zip(inputs, outputs, strict=True):
        assert out.intensity.shape == (3, 50, 30) and out.intensity.dtype == np.float32
        assert out.same_geometry(source) and 0.0 <= out.intensity.min() and out.intensity.max() <= 1.0
        assert np.array_equal(out.intensity[0], out.intensity[2])  # deterministic: n copies


def test_loader_rejects_a_checkpoint_of_another_model(tmp_path):
    (tmp_path / "other.json").write_text(json.dumps({"model": "cdfcvae"}))
    (tmp_path / "other.safetensors").write_bytes(b"")
    assert not is_cyclegan_checkpoint(tmp_path / "other.safetensors")
    with pytest.raises(FormatError, match="model"):
        CycleGANTranslator.from_checkpoint(tmp_path / "other.safetensors")


def test_train_cli_saves_every_nth_epoch_and_always_the_last(tmp_path):
    write_frames(frames(4, 0, speckle=False), tmp_path / "sim")
    write_frames(frames(4, 1, speckle=True), tmp_path / "real")
    (tmp_path / "tiny.json").write_text(json.dumps({"ngf": 4, "ndf": 4, "n_blocks": 1, "pool_size": 4}))
    common = ["train", "--model", "cyclegan", "--real", str(tmp_path / "real"), "--sim", str(tmp_path / "sim"),
              "--grid", "32x32", "--batch-size", "2", "--config", str(tmp_path / "tiny.json"), "--epochs", "3"]
    assert main([*common, "--out", str(tmp_path / "run"), "--save-every", "2"]) == 0
    meta = json.loads((tmp_path / "run" / "cyclegan.json").read_text())
    assert meta["epoch"] == 3 and [h["epoch"] for h in meta["history"]] == [1, 2, 3]
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        "cyclegan.json", "cyclegan.optim.safetensors", "cyclegan.safetensors"]  # nothing half-written left
    assert main([*common, "--out", str(tmp_path / "never"), "--save-every", "0"]) == 2
    assert not (tmp_path / "never").exists()


def test_crop_training_translates_whole_frames_at_their_own_resolution(tmp_path):
    write_frames(frames(4, 0, speckle=False, shape=(44, 36)), tmp_path / "sim")
    write_frames(frames(4, 1, speckle=True, shape=(52, 28)), tmp_path / "real")
    (tmp_path / "tiny.json").write_text(json.dumps({"ngf": 4, "ndf": 4, "n_blocks": 1, "pool_size": 4}))
    run = tmp_path / "run"
    common = ["train", "--model", "cyclegan", "--real", str(tmp_path / "real"), "--sim", str(tmp_path / "sim"),
              "--batch-size", "2", "--config", str(tmp_path / "tiny.json")]
    assert main([*common, "--out", str(run), "--crop", "24", "--epochs", "1"]) == 0
    meta = json.loads((run / "cyclegan.json").read_text())
    assert meta["grid"] is None and meta["crop"] == 24
    assert main([*common, "--out", str(run), "--epochs", "2", "--resume"]) == 0  # the crop comes from the checkpoint
    assert json.loads((run / "cyclegan.json").read_text())["crop"] == 24

    translator = CycleGANTranslator.from_checkpoint(run, device="cpu")
    padded = translator.translate(frames(1, 7, speckle=True, shape=(50, 30)), n=2)[0]  # sides padded, cut back
    assert padded.intensity.shape == (2, 50, 30)
    source = frames(1, 8, speckle=True, shape=(48, 28))[0]
    out = translator.translate([source], n=2)[0]
    assert out.intensity.shape == (2, 48, 28) and out.same_geometry(source)
    with torch.no_grad():
        direct = translator.generator(torch.from_numpy(source.intensity / np.float32(source.intensity.max()))
                                      [None, None] * 2 - 1)[0, 0].numpy()
    # the generator on the frame's own cells, not on a resampled grid
    assert np.allclose(out.intensity[1], np.clip((direct + 1) / 2, 0, 1), atol=1e-5)


def test_crop_larger_than_a_frame_or_given_with_a_grid_is_refused(tmp_path):
    write_frames(frames(2, 0, speckle=False, shape=(40, 24)), tmp_path / "sim")
    write_frames(frames(2, 1, speckle=True, shape=(40, 24)), tmp_path / "real")
    common = ["train", "--model", "cyclegan", "--real", str(tmp_path / "real"), "--sim", str(tmp_path / "sim"),
              "--out", str(tmp_path / "run"), "--epochs", "1"]
    assert main([*common, "--crop", "32"]) == 2  # the frames are 24 beams wide
    assert main([*common, "--crop", "16", "--grid", "32x32"]) == 2
    assert main([*common, "--crop", "18"]) == 2
    assert not (tmp_path / "run").exists()
