"""Depth-generator layers and network: partial convolution, cross-attention, uncertainty, learning."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from leovr.depth.layers import (
    CrossAttention,
    PartialConv2d,
    gaussian_nll,
    uncertainty_residual,
    uncertainty_weight,
)
from leovr.depth.network import DepthGenerator, GeneratorConfig, pyramid_fill


def test_partial_conv_ignores_invalid_inputs_and_rescales():
    torch.manual_seed(0)
    pc = PartialConv2d(1, 1, 3, 1, 1, bias=False)
    with torch.no_grad():
        pc.weight.fill_(1.0)
    x = torch.full((1, 1, 6, 6), 2.0)
    mask = torch.zeros(1, 1, 6, 6)
    mask[..., ::2, ::2] = 1.0
    garbage = x.clone()
    garbage[mask == 0] = 1e6  # values at invalid pixels must not leak into the output
    out, new_mask = pc(garbage, mask)
    valid = new_mask > 0
    assert valid.all()  # every 3x3 window sees at least one sample
    torch.testing.assert_close(out[valid], torch.full_like(out[valid], 18.0))  # same as a dense input of 2s
    dense, _ = pc(x, torch.ones_like(mask))
    torch.testing.assert_close(dense[..., 1:-1, 1:-1], F.conv2d(x, pc.weight)[..., :, :])
    empty_out, empty_mask = pc(x, torch.zeros_like(mask))
    assert empty_mask.sum() == 0 and empty_out.abs().sum() == 0


def test_cross_attention_shapes_and_convex_weights():
    torch.manual_seed(0)
    att = CrossAttention(8, 4)
    z_i, z_l = torch.randn(2, 8, 3, 5), torch.randn(2, 8, 3, 5)
    out = att(z_i, z_l)
    assert out.shape == (2, 16, 3, 5)
    # attention rows sum to one: a LiDAR feature constant over positions comes through unchanged
    const = torch.randn(2, 8, 1, 1).expand(2, 8, 3, 5).contiguous()
    torch.testing.assert_close(att(z_i, const)[:, :8], const)


def test_uncertainty_weight_and_residual_combination():
    sigma = torch.tensor([-10.0, 0.0, 10.0])
    lam = uncertainty_weight(sigma)
    torch.testing.assert_close(lam[1], torch.tensor(0.5))
    assert lam[0] > 0.999 and lam[2] < 0.001  # confident prior kept, uncertain prior replaced
    d = uncertainty_residual(torch.full((3,), 10.0), sigma, torch.full((3,), 20.0))
    torch.testing.assert_close(d, 10.0 * lam + 20.0 * (1 - lam))
    torch.testing.assert_close(uncertainty_weight(torch.tensor(1.0), 0.8, 0.0), torch.tensor(1 / (1 + math.exp(0.8))))


def test_gaussian_nll_hand_computed():
    pred, target = torch.tensor([3.0, 5.0]), torch.tensor([1.0, 5.0])
    log_sigma = torch.tensor([math.log(2.0), 0.0])
    valid = torch.tensor([1.0, 1.0])
    # pixel 1: 0.5 * (2 / 2)^2 + ln 2; pixel 2: 0
    assert gaussian_nll(pred, log_sigma, target, valid).item() == pytest.approx((0.5 + math.log(2.0)) / 2)


def test_pyramid_fill_fills_holes_from_valid_samples():
    s = torch.zeros(1, 1, 8, 8)
    s[0, 0, 1, 1], s[0, 0, 6, 6] = 3.0, 7.0
    f = pyramid_fill(s)
    assert (f > 0).all() and f[0, 0, 0, 0] == 3.0 and f[0, 0, 7, 7] == 7.0 and f[0, 0, 1, 1] == 3.0
    assert set(f.unique().tolist()) == {3.0, 7.0}


@pytest.mark.parametrize("encoder,attention", [("partial", True), ("interp", False)])
def test_generator_shapes_bottleneck_and_positive_depth(encoder, attention):
    torch.manual_seed(0)
    m = DepthGenerator(GeneratorConfig(lidar_encoder=encoder, cross_attention=attention)).eval()
    img = torch.rand(1, 3, 256, 448)
    sparse = torch.zeros(1, 1, 256, 448)
    sparse[..., 120:200:4, ::4] = 10.0
    with torch.no_grad():
        feats = m.rgb(img)
        depth, log_sigma = m(img, sparse)
    assert feats[-1].shape == (1, 128, 8, 14)  # LeoVR: cross-attention on 14 x 8 x 128
    assert depth.shape == log_sigma.shape == (1, 1, 256, 448) and (depth > 0).all()
    with pytest.raises(ValueError, match="multiple of 32"):
        m(torch.rand(1, 3, 250, 448), torch.zeros(1, 1, 250, 448))


def test_generator_learns_a_scene_and_sigma_head_is_separate():
    torch.manual_seed(0)
    m = DepthGenerator(GeneratorConfig(channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1)))
    img = torch.rand(2, 3, 64, 96)
    target = 5.0 + 10.0 * torch.linspace(0, 1, 96).view(1, 1, 1, 96).expand(2, 1, 64, 96)  # a slanted wall
    sparse = torch.zeros_like(target)
    sparse[..., ::6, ::6] = target[..., ::6, ::6]
    opt = torch.optim.Adam(m.depth_parameters(), lr=3e-3)
    losses = []
    for _ in range(40):
        depth, _ = m(img, sparse)
        loss = (depth - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.3 * losses[0]
    head = {id(p) for p in m.sigma_head.parameters()}
    assert head and not head & {id(p) for p in m.depth_parameters()}


def test_inference_loads_checkpoint_pads_any_size_and_rejects_bad_files(tmp_path):
    import numpy as np

    from leovr.depth.inference import load_generator, predict
    from leovr.errors import DataError

    torch.manual_seed(0)
    cfg = GeneratorConfig(channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1))
    model = DepthGenerator(cfg).eval()
    ckpt = tmp_path / "g.pt"
    torch.save({"model": model.state_dict(), "network": cfg.__dict__}, ckpt)
    loaded = load_generator(ckpt)
    img = np.random.default_rng(0).integers(0, 255, (75, 124, 3), dtype=np.uint8)  # not a multiple of 32
    sparse = np.zeros((75, 124), np.float32)
    sparse[::5, ::5] = 12.0
    d, s = predict(loaded, img, sparse)
    assert d.shape == s.shape == (75, 124) and (d > 0).all()
    db, _ = predict(loaded, np.stack([img, img]), np.stack([sparse, sparse]))
    np.testing.assert_allclose(db[1], d, rtol=1e-5)
    with pytest.raises(DataError, match="not found"):
        load_generator(tmp_path / "missing.pt")
    torch.save({"weights": 1}, tmp_path / "bad.pt")
    with pytest.raises(DataError, match="not a leovr depth-generator checkpoint"):
        load_generator(tmp_path / "bad.pt")
    other = {**cfg.__dict__, "channels": (8, 8, 16, 16, 32)}
    torch.save({"model": model.state_dict(), "network": other}, tmp_path / "mismatch.pt")
    with pytest.raises(DataError, match="does not match"):
        load_generator(tmp_path / "mismatch.pt")
    torch.save({"model": model.state_dict(), "network": {**cfg.__dict__, "output": "depth"}}, tmp_path / "out.pt")
    with pytest.raises(DataError, match="invalid network description.*output must be one of"):
        load_generator(tmp_path / "out.pt")
    (tmp_path / "corrupt.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match="unreadable checkpoint"):
        load_generator(tmp_path / "corrupt.pt")
