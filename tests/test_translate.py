"""Translator: n seeded samples per frame on the input's own geometry; the translate command."""

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from sonar_realism.errors import ConfigError, FormatError, FrameError
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.io import read_frames, write_frames
from sonar_realism.models.cdfcvae import CDFCVAE, CDFCVAEConfig, load_checkpoint, save_checkpoint
from sonar_realism.models.translate import DEFAULT_CHECKPOINT, Translator, add_arguments, load_translator, run

TINY = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8, 16), latent_dim=8, bottleneck_hw=(2, 2), skips=2)


@pytest.fixture
def checkpoint(tmp_path):
    import torch

    torch.manual_seed(0)
    model = CDFCVAE(TINY)
    with torch.no_grad():  # default init shrinks signals layer by layer; scale up so z visibly matters
        for weight in model.decoder.parameters():
            if weight.ndim > 1:
                weight.mul_(3.0)
    return save_checkpoint(model, tmp_path / "tiny.safetensors", {"normalisation": "frame_max"})


def _frame(seq=0, shape=(50, 40), seed=0):
    rng = np.random.default_rng(seed)
    # Non-uniform bearings, as an Oculus beam table has: the output must come back onto exactly these.
    azimuths = np.sin(np.linspace(-1.0, 1.0, shape[1])) * 1.1
    return SonarImage(rng.integers(0, 255, shape, dtype=np.uint8), uniform_ranges(shape[0], 30.0), azimuths,
                      seq=seq, stamp_ns=123 + seq, meta={"source": "sim"})


def test_n_samples_keep_the_input_geometry_and_differ(checkpoint):
    translator = Translator.from_checkpoint(checkpoint, device="cpu")
    frames = [_frame(0), _frame(1, shape=(64, 48), seed=1)]
    out = translator.translate(frames, n=4, temperature=1.0, seed=7)
    assert len(out) == 2
    for frame, result in zip(frames, out, strict=True):
        assert result.intensity.shape == (4, frame.n_ranges, frame.n_beams)
        assert result.intensity.dtype == np.float32
        assert 0.0 <= result.intensity.min() and result.intensity.max() <= 1.0
        assert result.same_geometry(frame) and (result.seq, result.stamp_ns) == (frame.seq, frame.stamp_ns)
        assert np.abs(result.intensity[0] - result.intensity[1]).mean() > 1e-3
        provenance = result.meta["provenance"]["translator"]
        assert provenance["seed"] == 7 and provenance["temperature"] == 1.0
        assert len(provenance["checkpoint_sha256"]) == 16
        assert result.meta["source"] == "sim"


def test_seed_repeats_and_a_frame_does_not_depend_on_the_frames_after_it(checkpoint):
    translator = Translator.from_checkpoint(checkpoint, device="cpu")
    frames = [_frame(0), _frame(1, seed=1)]
    a = translator.translate(frames, n=3, seed=11)
    b = translator.translate(frames, n=3, seed=11)
    c = translator.translate(frames, n=3, seed=12)
    alone = translator.translate(frames[:1], n=3, seed=11)
    assert all(np.array_equal(x.intensity, y.intensity) for x, y in zip(a, b, strict=True))
    assert np.abs(a[0].intensity - c[0].intensity).mean() > 1e-3
    assert np.allclose(a[0].intensity, alone[0].intensity, atol=1e-6)  # batch size may change float rounding


def test_temperature_zero_gives_the_posterior_mean_every_time(checkpoint):
    translator = Translator.from_checkpoint(checkpoint, device="cpu")
    out = translator.translate([_frame()], n=3, temperature=0.0, seed=1)[0].intensity
    assert np.array_equal(out[0], out[2])


def test_bad_arguments_are_rejected(checkpoint, tmp_path):
    translator = Translator.from_checkpoint(checkpoint, device="cpu")
    with pytest.raises(ConfigError):
        translator.translate([_frame()], n=0)
    with pytest.raises(ConfigError):
        translator.translate([_frame()], n=2, temperature=-1.0)
    multi = _frame().replace(intensity=np.zeros((2, 50, 40), np.uint8))
    with pytest.raises(FrameError, match="samples"):
        translator.translate([multi], n=2)
    with pytest.raises(FormatError, match="no such checkpoint"):
        Translator.from_checkpoint(tmp_path / "missing.safetensors")
    with pytest.raises(ConfigError, match="device"):
        Translator.from_checkpoint(checkpoint, device="tpu")


def test_translate_command_writes_frames_and_a_contact_sheet(checkpoint, tmp_path):
    write_frames([_frame(i, seed=i) for i in range(3)], tmp_path / "sim")
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--checkpoint", str(checkpoint), "--in", str(tmp_path / "sim"),
                              "--out", str(tmp_path / "out"), "--n", "2", "--seed", "3", "--device", "cpu"])
    assert run(args) == 0
    frames = list(read_frames(tmp_path / "out"))
    assert [f.seq for f in frames] == [0, 1, 2]
    assert all(f.intensity.shape == (2, 50, 40) for f in frames)
    assert (tmp_path / "out" / "contact_sheet.png").stat().st_size > 1000
    assert run(args) == 0  # same seed, same output
    again = list(read_frames(tmp_path / "out"))
    assert all(np.array_equal(x.intensity, y.intensity) for x, y in zip(frames, again, strict=True))


def test_translate_command_reads_a_bag_topic_and_writes_an_mcap_bag(checkpoint, tmp_path):
    write_frames([_frame(i, seed=i) for i in range(2)], tmp_path / "sim.mcap")
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--checkpoint", str(checkpoint), "--in", str(tmp_path / "sim.mcap"), "--topic",
                              "/sonar/image", "--out", str(tmp_path / "real.mcap"), "--n", "3", "--device", "cpu"])
    assert run(args) == 0
    frames = list(read_frames(tmp_path / "real.mcap"))
    assert [f.seq for f in frames] == [0, 1] and all(f.intensity.shape == (3, 50, 40) for f in frames)
    assert (tmp_path / "real.contact_sheet.png").stat().st_size > 1000


@pytest.mark.skipif(not DEFAULT_CHECKPOINT.exists(), reason="shipped checkpoint not present")
def test_shipped_checkpoint_loads_and_translates():
    model, info = load_checkpoint(DEFAULT_CHECKPOINT)
    assert DEFAULT_CHECKPOINT.stat().st_size <= 25 * 1024 * 1024
    translator = Translator.from_checkpoint(DEFAULT_CHECKPOINT, device="cpu")
    frame = _frame(shape=(96, 64))
    out = translator.translate([frame], n=2, seed=0)[0]
    assert out.intensity.shape == (2, 96, 64) and model.cfg.grid == translator.grid


@pytest.fixture
def texture_checkpoint(tmp_path):
    import torch

    from sonar_realism.models.speckle_fit import fit_speckle

    torch.manual_seed(0)
    config = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8), latent_dim=8, bottleneck_hw=(2, 2), skips=1,
                           output_stride=2, upsample="resize_conv", texture="speckle")
    model = CDFCVAE(config)
    rng = np.random.default_rng(0)
    model.texture.set_fit(*fit_speckle([rng.gamma(2.0, 0.5, (64, 64)) for _ in range(3)], [np.ones((64, 64))] * 3))
    return save_checkpoint(model, tmp_path / "texture.safetensors", {"normalisation": "frame_max"})


def test_texture_model_samples_carry_speckle_and_temperature_zero_gives_the_mean(texture_checkpoint):
    translator = Translator.from_checkpoint(texture_checkpoint, device="cpu")
    frames = [_frame(0, shape=(80, 64)), _frame(1, shape=(80, 64), seed=1)]
    speckled = translator.translate(frames, n=3, seed=5)
    mean = translator.translate(frames, n=2, temperature=0.0, seed=5)
    for noisy, smooth, frame in zip(speckled, mean, frames, strict=True):
        assert noisy.intensity.shape == (3, 80, 64) and noisy.same_geometry(frame)
        # Samples are the sensor's 8-bit export, sent as such; the posterior mean is not quantised.
        assert (noisy.intensity.dtype, noisy.intensity_scale) == (np.uint8, 255.0)
        assert (smooth.intensity.dtype, smooth.intensity_scale) == (np.float32, 1.0)
        assert noisy.intensity.reshape(3, -1).max(axis=1).tolist() == [255] * 3  # each scaled to its maximum
        # Per-pixel texture: neighbouring cells of one sample differ far more than the smooth mean's do.
        roughness = lambda x: np.abs(np.diff(x, axis=-1)).mean()  # noqa: E731
        assert roughness(noisy.normalized()[0]) > 3 * roughness(smooth.normalized()[0])
        assert np.abs(noisy.normalized()[0] - noisy.normalized()[1]).mean() > 0.01
        np.testing.assert_array_equal(smooth.intensity[0], smooth.intensity[1])
    again = translator.translate(frames, n=3, seed=5)
    np.testing.assert_array_equal(again[1].intensity, speckled[1].intensity)
    other = translator.translate(frames, n=3, seed=6)[1]
    assert np.abs(other.normalized() - speckled[1].normalized()).mean() > 0.01


def tiny_cyclegan(folder):
    import torch
    from safetensors.torch import save_file

    from sonar_realism.models.cyclegan import CycleGAN, CycleGANConfig

    folder.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    model = CycleGAN(CycleGANConfig(ngf=4, ndf=4, n_blocks=1))
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(folder / "cyclegan.safetensors"))
    (folder / "cyclegan.json").write_text(json.dumps({"model": "cyclegan", "config": {"ngf": 4, "ndf": 4,
                                                                                       "n_blocks": 1},
                                                      "grid": [32, 32]}))
    return folder


def test_one_loader_tells_a_cdfcvae_from_a_cyclegan_checkpoint(checkpoint, tmp_path):
    from sonar_realism.models.cyclegan import CycleGANTranslator

    cdfcvae = load_translator(checkpoint, "cpu")
    assert isinstance(cdfcvae, Translator)
    assert cdfcvae.checkpoint_sha256 == hashlib.sha256(Path(checkpoint).read_bytes()).hexdigest()
    cyclegan = load_translator(tiny_cyclegan(tmp_path), "cpu")
    assert isinstance(cyclegan, CycleGANTranslator) and cyclegan.grid == (32, 32)
    assert cyclegan.translate([_frame()], n=2)[0].intensity.shape == (2, 50, 40)
    for path in (checkpoint, tmp_path):
        with pytest.raises(ConfigError, match="device 'tpu'"):
            load_translator(path, "tpu")



def test_translate_command_refuses_to_write_into_the_recording_it_reads(checkpoint, tmp_path):
    write_frames([_frame(i, seed=i) for i in range(2)], tmp_path / "sim")
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--checkpoint", str(checkpoint), "--in", str(tmp_path / "sim"),
                              "--out", str(tmp_path / "sim" / "."), "--device", "cpu"])
    with pytest.raises(ConfigError, match="--out .* is the --in recording"):
        run(args)
    assert len(list(read_frames(tmp_path / "sim"))) == 2  # nothing read was removed


def test_translate_command_says_what_it_could_not_read(checkpoint, tmp_path, capsys):
    # a capture cut short inside its last ping: the whole pings are translated and the cut one is reported
    data = (Path(__file__).parent / "data" / "three_pings_8bit.raw").read_bytes()
    (tmp_path / "cut.raw").write_bytes(data[: int(len(data) * 0.9)])
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--checkpoint", str(checkpoint), "--in", str(tmp_path / "cut.raw"),
                              "--out", str(tmp_path / "out"), "--n", "1", "--device", "cpu"])
    assert run(args) == 0
    assert len(list(read_frames(tmp_path / "out"))) == 2
    assert "1 record(s) could not be read" in capsys.readouterr().err


def test_a_checkpoint_with_an_unknown_normalisation_is_refused(checkpoint):
    info_path = checkpoint.with_suffix(".json")
    info = json.loads(info_path.read_text())
    info["normalisation"] = "bogus"
    info_path.write_text(json.dumps(info))
    with pytest.raises(FormatError, match="normalisation.*'bogus' is none of frame_max, full_scale"):
        Translator.from_checkpoint(checkpoint, device="cpu")
