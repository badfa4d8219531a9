"""Fitted photometry (model.photometry: fitted): the lens radius against rigjax's camera geometry,
and the exposures and vignetting of a rendered rig against the ones applied to it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learnstitch.config import config_from_dict
from learnstitch.data.rig import fisheye_rays, nominal_centres, pano_rays, unwarp_grids
from learnstitch.data.sample import SynthConfig, make_sample, unwarp
from learnstitch.network import build_model
from learnstitch.network.depth import DepthStitchNet
from learnstitch.network.model import ModelConfig, corrects_colour
from learnstitch.network.photometry import correction, fit_photometry, lens_radius
from rigjax.errors import ConfigError

CLEAN = SynthConfig(fisheye_size=128, pano_width=256, distance=0.4, gain_jitter=0.0, vignetting=0.0, noise_std=0.0)
GAINS, VIGNETTING = torch.tensor([1.12, 0.9, 1.0]), 0.25


@pytest.fixture(scope="module")
def rendered():
    """A clean sample, the same with known gains, vignetting (the renderer's law) and noise, and
    both unwarped at the sample's cameras and warped through its true depth."""
    sample = make_sample(CLEAN, 1_000_000_001)
    _, _, theta = fisheye_rays(sample.rig.cameras, CLEAN.circle_deg)
    radius = torch.as_tensor(np.clip(theta / (CLEAN.circle_deg / 2.0), 0.0, 1.0), dtype=torch.float32)
    factor = GAINS[:, None, None] * (1.0 - VIGNETTING * radius**2)  # (3, S, S)
    noise = 0.01 * torch.randn(sample.fisheyes.shape, generator=torch.Generator().manual_seed(5))
    dirty = (sample.fisheyes * factor[:, None] + noise).clamp(0.0, 1.0) * sample.fisheye_masks[:, None]
    grids, masks, angles = unwarp_grids(sample.rig.cameras, (CLEAN.pano_width, CLEAN.pano_height), CLEAN.circle_deg)
    net = DepthStitchNet(ModelConfig(warp="depth", widths=(4,), depth_planes=2), nominal_centres(CLEAN.distance))
    rays = torch.as_tensor(pano_rays(CLEAN.pano_width, CLEAN.pano_height), dtype=torch.float32)
    identity = torch.eye(3).expand(1, 3, 3, 3)
    warped = {}
    for name, fisheyes in (("clean", sample.fisheyes), ("dirty", dirty)):
        x = torch.cat([unwarp(fisheyes, grids), masks.float()[:, None]], dim=1)[None]
        r = lens_radius(x[:, :, 3], rays)
        warped[name] = net.warp(torch.cat([x, r[:, :, None]], dim=2), (1.0 / sample.depth)[None], identity)[0]
    # Where each input is whole, the factor the renderer applied there, on the panorama canvas.
    whole = unwarp(torch.ones(3, 1, CLEAN.fisheye_size, CLEAN.fisheye_size), grids)[:, 0] > 0.999
    applied = unwarp(factor[:, None], grids)[:, 0]
    return {"warped": warped, "radius": r[0], "angles": angles, "masks": masks & whole, "applied": applied}


def test_the_lens_radius_is_the_angle_from_each_cameras_axis_over_the_circles_half_angle(rendered):
    # From the masks alone; the reference is rigjax's ray_to_img angles of the sample's own cameras.
    expected = rendered["angles"] / (CLEAN.circle_deg / 2.0)
    inside = rendered["masks"]
    error = (rendered["radius"] - expected)[inside].abs()
    assert error.max() < 0.005, error.max()


def test_a_clean_rig_fits_no_correction(rendered):
    w = rendered["warped"]["clean"]
    exposure, vignetting = fit_photometry(w[None, :, :3], w[None, :, 3], w[None, :, 4])
    factor = correction(exposure, vignetting, rendered["radius"][None])[0]
    error = (factor - 1.0)[rendered["masks"]].abs()
    assert error.mean() < 0.01 and error.quantile(0.99) < 0.02, (error.mean(), error.quantile(0.99))


def test_the_fit_recovers_the_gains_and_vignetting_applied(rendered):
    w = rendered["warped"]["dirty"]
    exposure, vignetting = fit_photometry(w[None, :, :3], w[None, :, 3], w[None, :, 4])
    # Exposure differences are the log gain ratios; the overall exposure is held at the mean.
    np.testing.assert_allclose(
        (exposure[0, :, None] - exposure[0, None, :]).numpy(),
        (GAINS.log()[:, None] - GAINS.log()[None, :]).numpy(),
        atol=0.01,
    )
    assert abs(float(exposure.sum())) < 1e-6
    # The correction undoes what was applied, up to the overall exposure (the gains' mean, 0.7 %).
    factor = correction(exposure, vignetting, rendered["radius"][None])[0]
    undone = (factor * rendered["applied"])[rendered["masks"]]
    assert (undone - 1.0).abs().mean() < 0.025 and (undone - 1.0).abs().max() < 0.05
    # The vignetting at the circle's edge: the renderer's 1 - 0.25 there.
    edge = float(vignetting[0].sum().exp())
    assert edge == pytest.approx(1.0 - VIGNETTING, abs=0.03)


def test_fitted_photometry_is_a_depth_warp_option_and_switches_off():
    values = {"warp": "depth", "widths": [4, 8, 8], "regressor_width": 8, "head_width": 4, "depth_planes": 4}
    config = config_from_dict(
        {"model": {**values, "photometry": "fitted"}, "data": {"fisheye_size": 32, "pano_width": 64}}, "p.yaml"
    )
    model = build_model(config.model, config.data)
    assert model.gain_head is None and corrects_colour(model)
    g = torch.Generator().manual_seed(2)
    inputs, masks = torch.rand(1, 3, 3, 32, 64, generator=g) * 0.8 + 0.1, torch.ones(1, 3, 32, 64)
    bright = inputs * torch.tensor([1.2, 1.0, 1.0])[None, :, None, None, None]
    with torch.no_grad():
        fitted, off = model(bright, masks).pano, model(bright, masks, gain=False).pano
    assert (fitted - off).abs().max() > 0.01  # the fit corrects; gain=False does not
    with pytest.raises(ConfigError, match="photometry: fitted needs warp: depth"):
        config_from_dict({"model": {"photometry": "fitted"}}, "h.yaml")
    with pytest.raises(ConfigError, match="photometry must be 'maps' or 'fitted', got 'auto'"):
        config_from_dict({"model": {**values, "photometry": "auto"}}, "a.yaml")
