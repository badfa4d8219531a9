"""The stitching network's geometry, blend and losses against closed forms and independent references."""

from __future__ import annotations

import kornia
import pytest
import torch
import torch.nn.functional as F

from learnstitch.baselines import psnr
from learnstitch.data.sample import SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from learnstitch.network.losses import LossConfig, StitchLoss, VGG16Features, load_vgg16, ssim_loss
from learnstitch.network.model import ModelConfig, StitchNet, StitchOutput, parameter_count
from learnstitch.network.warp import base_grid, homographies_from_corners, homography_grids, sample_wrapped
from rigjax.errors import ConfigError

SMALL = ModelConfig(homographies=2, widths=(4, 8, 8), regressor_width=8, head_width=4)


def _apply(h: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    p = torch.cat([xy, torch.ones_like(xy[..., :1])], dim=-1) @ h.transpose(-1, -2)
    return p[..., :2] / p[..., 2:]


def test_corner_offsets_give_the_homography_through_the_moved_corners():
    torch.manual_seed(0)
    offsets = 0.2 * (torch.rand(5, 4, 2, dtype=torch.float64) * 2 - 1)
    h = homographies_from_corners(offsets)
    corners = torch.tensor([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(_apply(h, corners.expand(5, 4, 2)), corners + offsets, atol=1e-12, rtol=0)
    identity = homographies_from_corners(torch.zeros(4, 2, dtype=torch.float64))
    torch.testing.assert_close(identity, torch.eye(3, dtype=torch.float64), atol=1e-12, rtol=0)


def test_a_translation_of_the_corners_translates_the_grid():
    shift = torch.tensor([0.1, -0.05], dtype=torch.float64)
    grid = homography_grids(homographies_from_corners(shift.expand(4, 2)), 6, 12)
    torch.testing.assert_close(grid, base_grid(6, 12, dtype=torch.float64) + shift, atol=1e-12, rtol=0)


def test_the_grid_is_differentiable_in_the_offsets():
    torch.manual_seed(1)
    offsets = (0.1 * torch.randn(2, 4, 2, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda o: homography_grids(homographies_from_corners(o), 3, 5), (offsets,))


@pytest.mark.parametrize("shift", [3, -2, 5])
def test_sampling_wraps_around_the_panorama_like_a_roll(shift):
    torch.manual_seed(2)
    image = torch.rand(1, 3, 8, 16, dtype=torch.float64)
    grid = base_grid(8, 16, dtype=torch.float64) + torch.tensor([2.0 * shift / 16, 0.0], dtype=torch.float64)
    sampled = sample_wrapped(image, grid[None], wrap=0.5)
    torch.testing.assert_close(sampled, torch.roll(image, -shift, dims=-1), atol=1e-12, rtol=0)
    # Without wrap-around the columns that leave the canvas are zero.
    plain = sample_wrapped(image, grid[None], wrap=0.0)
    outside = slice(16 - shift, None) if shift > 0 else slice(0, -shift)
    assert plain[..., outside].abs().max() == 0


def _inputs(batch=2, height=16, width=32, seed=3):
    g = torch.Generator().manual_seed(seed)
    masks = (torch.rand(batch, 3, height, width, generator=g) > 0.4).float()
    masks[:, 0] = 1.0  # every pixel seen by input 0
    return torch.rand(batch, 3, 3, height, width, generator=g) * masks[:, :, None], masks


def test_the_untrained_network_blends_the_inputs_where_they_are():
    """Identity warps and equal weights: the mean of the inputs that see each pixel."""
    inputs, masks = _inputs()
    out = StitchNet(SMALL)(inputs, masks)
    expected = inputs.sum(dim=1) / masks.sum(dim=1)[:, None]
    # float32: kornia's DLT gives the identity to ~1e-7, which moves the samples by as much
    torch.testing.assert_close(out.pano, expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(out.weights.sum(dim=(1, 2)), torch.ones_like(masks[:, 0]), atol=1e-6, rtol=0)
    torch.testing.assert_close(out.input_from_output, torch.eye(3).expand_as(out.input_from_output), atol=1e-6, rtol=0)


@pytest.mark.parametrize("chosen", [0, 1, 2])
def test_a_hand_set_identity_network_reproduces_each_unwarped_input(chosen):
    inputs, masks = _inputs()
    net = StitchNet(SMALL)
    with torch.no_grad():  # the weight head's logits: 30 for every warp of input `chosen`, 0 for the others
        k = SMALL.homographies
        net.weight_head.bias.copy_(torch.tensor([30.0 if i // k == chosen else 0.0 for i in range(3 * k)]))
    out = net(inputs, masks)
    seen = masks[:, chosen, None].expand_as(out.pano) > 0
    torch.testing.assert_close(out.pano[seen], inputs[:, chosen][seen], atol=1e-5, rtol=0)


def test_with_the_true_orientations_and_no_offset_the_identity_network_is_the_panorama():
    """d = 0, no jitter: the unwarped inputs are the truth wherever they see; their blend is the
    ground truth up to resampling: 39.1-40.3 dB measured (seeds 11-13) after a 1.5 px blur, against 25-27 dB
    for the same scenes at d = 0.2, so 35 dB separates "represents the answer" from parallax."""
    config = SynthConfig(
        fisheye_size=192,
        pano_width=128,
        distance=0.0,
        angle_jitter_deg=0.0,
        hfov_jitter_deg=0.0,
        gain_jitter=0.0,
        vignetting=0.0,
        noise_std=0.0,
    )
    sample = make_sample(config, 11)
    grids, masks, _ = nominal_unwarp_grids(config)
    pano = StitchNet(SMALL)(unwarp(sample.fisheyes, grids)[None], masks.float()[None]).pano[0]
    blur = lambda x: kornia.filters.gaussian_blur2d(x[None], (7, 7), (1.5, 1.5))[0]  # noqa: E731
    assert float(psnr(blur(pano.detach()), blur(sample.pano))) > 35.0


def test_inputs_of_the_wrong_count_or_size_are_refused():
    net = StitchNet(SMALL)
    inputs, masks = _inputs()
    with pytest.raises(ConfigError, match=r"expected inputs \(B, 3, 3, H, W\)"):
        net(inputs[:, :2], masks[:, :2])
    with pytest.raises(ConfigError, match="not a multiple of the encoder's stride 8"):
        net(inputs[..., :20], masks[..., :20])


def test_gradients_reach_every_parameter_after_one_step():
    torch.manual_seed(4)
    net = StitchNet(SMALL)
    inputs, masks = _inputs()
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(2):  # zero-initialised heads: the layers before them get gradients from the second step
        optimiser.zero_grad()
        (net(inputs, masks).pano - inputs[:, 0]).abs().mean().backward()
        optimiser.step()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.parameters())
    assert parameter_count(net) == sum(p.numel() for p in net.parameters())


# --- losses -------------------------------------------------------------------------------------


def test_ssim_loss_is_one_minus_ssim_not_kornias_half():
    torch.manual_seed(5)
    a, b = torch.rand(2, 3, 24, 24), torch.rand(2, 3, 24, 24)
    assert float(ssim_loss(a, a)) == pytest.approx(0.0, abs=1e-6)
    assert float(ssim_loss(a, b)) == pytest.approx(2.0 * float(kornia.losses.ssim_loss(a, b, 11)), rel=1e-5)


def _output(pano: torch.Tensor) -> StitchOutput:
    """A network's output of which the loss reads only the panorama."""
    return StitchOutput(pano, coverage=torch.ones_like(pano[:, 0]), weights=torch.ones_like(pano[:, None, None, 0]))


def test_the_loss_weights_its_terms_by_beta():
    torch.manual_seed(6)
    a, b = torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 16)
    total, terms = StitchLoss(LossConfig(beta=0.4))(_output(a), {"pano": b})
    assert float(terms["pixel"]) == pytest.approx(float((a - b).abs().mean()), rel=1e-6)
    assert float(total) == pytest.approx(0.4 * float(terms["pixel"]) + 0.6 * float(ssim_loss(a, b)), rel=1e-6)
    total, terms = StitchLoss(LossConfig(beta=1.0))(_output(a), {"pano": b})
    assert set(terms) == {"pixel"}


def _random_vgg_file(path):
    torch.manual_seed(7)
    state = {f"features.{k}": v for k, v in VGG16Features().features.state_dict().items()}
    state["classifier.0.weight"] = torch.zeros(2, 2)  # a full torchvision file also holds the classifier
    torch.save(state, path)
    return state


def test_vgg16_has_torchvisions_parameter_names_and_loads_a_state_dict(tmp_path):
    names = {k for k in VGG16Features().state_dict()}
    expected = {
        f"features.{i}.{p}" for i in (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28) for p in ("weight", "bias")
    }
    assert names == expected
    state = _random_vgg_file(tmp_path / "vgg16.pth")
    vgg = load_vgg16(tmp_path / "vgg16.pth")
    assert torch.equal(vgg.features[28].bias, state["features.28.bias"])
    assert not any(p.requires_grad for p in vgg.parameters())


def test_the_perceptual_loss_is_l1_between_pool_features(tmp_path):
    """Block weights (1, 0, 0, 0, 0): the first block by hand, from the state dict."""
    state = _random_vgg_file(tmp_path / "vgg16.pth")
    config = LossConfig(
        pixel="perceptual", beta=1.0, vgg_weights=str(tmp_path / "vgg16.pth"), vgg_block_weights=(1, 0, 0, 0, 0)
    )
    torch.manual_seed(8)
    a, b = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)

    def block1(x):
        x = (x - torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)) / torch.tensor([0.229, 0.224, 0.225]).view(
            1, 3, 1, 1
        )
        x = F.relu(F.conv2d(x, state["features.0.weight"], state["features.0.bias"], padding=1))
        x = F.relu(F.conv2d(x, state["features.2.weight"], state["features.2.bias"], padding=1))
        return F.max_pool2d(x, 2)

    total, _ = StitchLoss(config)(_output(a), {"pano": b})
    assert float(total) == pytest.approx(float((block1(a) - block1(b)).abs().mean()), rel=1e-5)
    assert float(StitchLoss(config)(_output(a), {"pano": a})[0]) == 0.0


def test_a_missing_vgg_file_says_what_to_provide(tmp_path):
    with pytest.raises(ConfigError, match=r"nope.pth: VGG-16 weights not found .*vgg16-397923af.pth"):
        StitchLoss(LossConfig(pixel="perceptual", vgg_weights=str(tmp_path / "nope.pth")))
    with pytest.raises(ConfigError, match="loss.vgg_weights is not set"):
        StitchLoss(LossConfig(pixel="perceptual"))
    (tmp_path / "other.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="other.pth: not a loadable state dict"):
        load_vgg16(tmp_path / "other.pth")
