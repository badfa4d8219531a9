"""One network for any rig: random rigs as training data, batches of rigs of several sizes, the
pooled rig-aware network, and the training's start from a trained model — each against an
independent reference (rigjax's camera axes, the same rig alone or in another order, a fit
without the absent input, the checkpoint's own tensors)."""

import copy
import dataclasses

import jax
import numpy as np
import pytest
import torch

import learnstitch
from learnstitch.checkpoint import CHECKPOINT_FORMAT, save_checkpoint
from learnstitch.config import StitchConfig, config_as_dict, config_from_dict
from learnstitch.data.datasets import FolderDataset, GeneratedDataset, collate_rigs
from learnstitch.data.generate import synthesise
from learnstitch.data.rigs import random_shape
from learnstitch.data.sample import SynthConfig, make_sample
from learnstitch.fullres.rig import load_rig
from learnstitch.inference import stitch_fisheyes
from learnstitch.network import build_model
from learnstitch.network.model import ModelConfig
from learnstitch.network.photometry import fit_photometry
from learnstitch.training import _initialise_from
from rigjax.errors import ConfigError

RANDOM = SynthConfig(fisheye_size=48, pano_width=64, rig="random", tri_share=0.0)
POOLED = ModelConfig(
    warp="depth",
    inputs="calibrated",
    pooling="pooled",
    max_rotation_deg=0.0,
    widths=(4, 6, 8),
    regressor_width=8,
    head_width=4,
    photometry="fitted",
    depth_planes=6,
    max_inverse_depth=2.0,
    fill=True,
)


def test_random_rigs_draw_every_camera_count_and_lens_with_overlapping_neighbours():
    rng = np.random.default_rng(0)
    counts = set()
    for _ in range(150):
        shape = random_shape(rng, 64, RANDOM)
        n = len(shape.yaws)
        counts.add(n)
        assert RANDOM.hfov_range[0] <= shape.hfov <= RANDOM.hfov_range[1]
        assert 0.01 <= shape.distance <= RANDOM.max_distance
        # rigjax's own optical axes: the centres lie along them, and the neighbours' axes are less
        # than the lens's field apart (their image circles overlap)
        cameras = jax.tree_util.tree_map(jax.numpy.asarray, shape.nominal())
        axes = np.asarray(jax.vmap(lambda c: c.world_from_cam[:, 2])(cameras))
        np.testing.assert_allclose(shape.centres(), shape.distance * axes, atol=1e-12)
        order = np.argsort(np.mod(shape.yaws, 360.0))
        for a, b in zip(order, np.roll(order, -1)):
            assert np.degrees(np.arccos(np.clip(axes[a] @ axes[b], -1.0, 1.0))) < shape.hfov - 10.0
        # every horizontal direction lies inside some camera's image circle
        azimuth = np.radians(np.arange(0.0, 360.0, 2.0))
        horizon = np.stack([np.sin(azimuth), np.zeros_like(azimuth), np.cos(azimuth)], axis=-1)
        assert (np.degrees(np.arccos(np.clip(horizon @ axes.T, -1.0, 1.0))).min(axis=1) < shape.hfov / 2.0).all()
    assert counts == {2, 3, 4, 5, 6}


def test_a_random_rig_config_mixes_in_the_three_fisheye_rig_of_its_other_keys():
    mixed = dataclasses.replace(RANDOM, tri_share=0.5)
    tri = dataclasses.replace(RANDOM, rig="tri")
    samples = [make_sample(mixed, seed) for seed in range(8)]
    three = [s for s in samples if len(s.fisheyes) == 3 and s.circle_deg == tri.circle_deg]
    assert 0 < len(three) < 8
    for sample in three:  # bit for bit the three-fisheye config's sample of that seed
        assert torch.equal(sample.fisheyes, make_sample(tri, sample.seed).fisheyes)


def test_random_rigs_round_trip_through_disk_and_open_as_projects(tmp_path):
    synthesise(RANDOM, tmp_path, num=3, progress=False)
    disk = FolderDataset(tmp_path, "train", inputs="calibrated")
    fresh = GeneratedDataset(RANDOM, "train", 3, inputs="calibrated")
    for k in range(3):
        a, b = disk[k], fresh[k]
        sample = make_sample(RANDOM, k)
        assert a["inputs"].shape[0] == b["inputs"].shape[0] == len(sample.fisheyes)
        assert torch.equal(a["masks"], b["masks"])
        torch.testing.assert_close(a["centres"], torch.as_tensor(sample.rig.centres, dtype=torch.float32))
        assert (a["inputs"] - b["inputs"]).abs().max() <= 1.0 / 255.0 + 1e-6  # PNG quantisation
        rig = load_rig(tmp_path / "train" / f"{k:06d}" / "rig.pto")
        assert len(rig.images) == len(sample.fisheyes)
        np.testing.assert_allclose(rig.centres, sample.rig.centres, atol=1e-9)


def test_batches_pad_smaller_rigs_with_absent_cameras():
    def item(n):
        return {
            "inputs": torch.rand(n, 3, 4, 8),
            "masks": torch.ones(n, 4, 8),
            "centres": torch.rand(n, 3),
            "pano": torch.rand(3, 4, 8),
            "seed": n,
        }

    items = [item(2), item(5), item(3)]
    batch = collate_rigs(items)
    assert batch["inputs"].shape == (3, 5, 3, 4, 8) and batch["centres"].shape == (3, 5, 3)
    for k, it in enumerate(items):
        n = len(it["inputs"])
        assert torch.equal(batch["inputs"][k, :n], it["inputs"]) and torch.equal(batch["masks"][k, :n], it["masks"])
        assert not batch["masks"][k, n:].any() and not batch["inputs"][k, n:].any()
    assert batch["seed"].tolist() == [2, 5, 3]


def _randomised(model: torch.nn.Module) -> torch.nn.Module:
    """Every weight random (the zero-initialised heads too: a head at zero hides the inputs' order)."""
    torch.manual_seed(1)
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.normal_(0.0, 0.3)
    return model.eval()


def _rig(index: int) -> dict:
    return GeneratedDataset(RANDOM, "train", index + 1, inputs="calibrated")[index]


def test_a_pooled_network_ignores_the_order_and_the_padding_of_its_inputs():
    net = _randomised(build_model(POOLED, RANDOM))
    item = _rig(1)
    batch = collate_rigs([item])
    n = batch["inputs"].shape[1]
    assert n >= 3
    order = torch.as_tensor(np.random.default_rng(0).permutation(n))
    padded = collate_rigs([item, _rig(3)])  # a rig of another size in the same batch pads one of them
    assert padded["inputs"].shape[1] > n
    with torch.no_grad():
        base = net(batch["inputs"], batch["masks"], centres=batch["centres"])
        turned = net(batch["inputs"][:, order], batch["masks"][:, order], centres=batch["centres"][:, order])
        both = net(padded["inputs"], padded["masks"], centres=padded["centres"])
    assert base.inverse_depth.std() > 0.0
    for out in (turned, both):
        torch.testing.assert_close(out.inverse_depth[:1], base.inverse_depth, atol=1e-4, rtol=0)
        # float32 rounding: a batch of another size runs other kernel blockings, and one machine's gave
        # one pixel 1.0002e-4 apart (mean 3e-7); a network that sees the order differs by 1e-2 and more
        torch.testing.assert_close(out.pano[:1], base.pano, atol=5e-4, rtol=0)
    # The reference can tell: a network that concatenates its inputs does see their order.
    concat = _randomised(build_model(dataclasses.replace(POOLED, pooling="concat", max_rotation_deg=5.0), RANDOM))
    with torch.no_grad():
        a = concat(batch["inputs"], batch["masks"], centres=batch["centres"]).pano
        b = concat(batch["inputs"][:, order], batch["masks"][:, order], centres=batch["centres"][:, order]).pano
    assert (a - b).abs().max() > 1e-2


def test_a_pooled_network_keeps_a_rigs_grids_only_for_that_rig():
    """The sweep's grids of the last centres are kept (a clip's frames share its rig); other
    centres get their own, as a fresh network computes them."""
    net = _randomised(build_model(POOLED, RANDOM))
    batch = collate_rigs([_rig(1)])
    wider = batch["centres"] * 1.5
    with torch.no_grad():
        first = net(batch["inputs"], batch["masks"], centres=batch["centres"])
        other = net(batch["inputs"], batch["masks"], centres=wider)
        again = net(batch["inputs"], batch["masks"], centres=batch["centres"])
        fresh = copy.deepcopy(net)
        fresh._last_rig = None
        expected = fresh(batch["inputs"], batch["masks"], centres=wider)
    assert (other.inverse_depth - first.inverse_depth).abs().max() > 1e-3  # the centres matter here
    torch.testing.assert_close(other.pano, expected.pano, atol=0, rtol=0)
    torch.testing.assert_close(again.pano, first.pano, atol=0, rtol=0)


def test_stitch_fisheyes_runs_a_network_of_any_rig_on_a_two_camera_sample():
    # The user-facing stitch at the network's size against the dataset's own unwarp of the same
    # sample (learnstitch.data.datasets) fed to the network with the sample's centres.
    net = _randomised(build_model(POOLED, RANDOM)).eval()
    index = next(k for k in range(100) if len(_rig(k)["centres"]) == 2)
    item = _rig(index)
    sample = make_sample(RANDOM, item["seed"])
    assert len(sample.fisheyes) == 2
    cameras, centres = sample.rig.cameras, sample.rig.centres
    got = stitch_fisheyes(net, sample.fisheyes, RANDOM, cameras, centres, circle_deg=sample.circle_deg)
    with torch.no_grad():
        expected = net(item["inputs"][None], item["masks"][None], centres=item["centres"][None]).pano[0]
    assert got.shape == (3, RANDOM.pano_height, RANDOM.pano_width) and got.std() > 0.01
    torch.testing.assert_close(got, expected.clamp(0.0, 1.0), atol=1e-6, rtol=0)
    with pytest.raises(ConfigError, match=r"a network of any rig .* pass centres"):
        stitch_fisheyes(net, sample.fisheyes, RANDOM, cameras, circle_deg=sample.circle_deg)
    # Under its former name, the sample's rig as given; without its centres, refused, not stitched
    # through the three-fisheye rig's.
    torch.testing.assert_close(
        learnstitch.stitch(
            net,
            sample.fisheyes,
            dataclasses.replace(RANDOM, circle_deg=sample.circle_deg),
            cameras=cameras,
            centres=centres,
        ),
        got,
        atol=0,
        rtol=0,
    )
    with pytest.raises(ConfigError, match=r"a network of any rig .* pass centres"):
        learnstitch.stitch(net, sample.fisheyes, RANDOM, cameras=cameras)
    with pytest.raises(ConfigError, match=r"2 fisheyes, but the calibration has 3 cameras"):
        three = make_sample(dataclasses.replace(RANDOM, rig="tri"), 0).rig.cameras
        stitch_fisheyes(net, sample.fisheyes, RANDOM, three, centres)


def test_the_exposure_fit_leaves_an_absent_input_out():
    # Three inputs seeing one gradient with known exposures; the same with a fourth, absent input
    # (no pixels) must give the three-input fit, and the absent input's exposure 0.
    torch.manual_seed(0)
    height, width = 16, 32
    radiance = 0.2 + 0.6 * torch.rand(3, height, width)
    exposure = torch.tensor([0.1, -0.05, -0.05])
    rgb = radiance[None, None] * exposure.exp()[None, :, None, None, None]
    alpha = torch.ones(1, 3, height, width)
    radius = torch.rand(1, 3, height, width)
    alone = fit_photometry(rgb, alpha, radius)
    pad = lambda t: torch.cat([t, torch.zeros_like(t[:, :1])], dim=1)
    present = torch.tensor([[True, True, True, False]])
    with_absent = fit_photometry(pad(rgb), pad(alpha), pad(radius), present)
    torch.testing.assert_close(alone[0][0], exposure, atol=1e-4, rtol=0)
    torch.testing.assert_close(with_absent[0][0, :3], alone[0][0], atol=1e-6, rtol=0)
    assert abs(float(with_absent[0][0, 3])) < 1e-6


def test_a_run_starts_from_the_weights_it_shares_with_a_checkpoint(tmp_path):
    donor = build_model(dataclasses.replace(POOLED, pooling="concat", max_rotation_deg=5.0), RANDOM)
    path = tmp_path / "model.pt"
    config = StitchConfig(data=RANDOM, model=POOLED)
    save_checkpoint(path, {"format": CHECKPOINT_FORMAT, "config": config_as_dict(config), "model": donor.state_dict()})
    torch.manual_seed(5)
    model = build_model(POOLED, RANDOM)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    shared = _initialise_from(model, str(path))
    theirs, mine = donor.state_dict(), model.state_dict()
    copied = [k for k in mine if k in theirs and theirs[k].shape == mine[k].shape]
    assert shared == len(copied) and any(k.startswith("encoder.") for k in copied)
    for key, value in mine.items():
        assert torch.equal(value, theirs[key] if key in copied else before[key]), key
    other = tmp_path / "other.pt"
    save_checkpoint(other, {"format": CHECKPOINT_FORMAT, "config": {}, "model": {"unrelated": torch.zeros(1)}})
    with pytest.raises(ConfigError, match="train.init_from: .*other.pt shares no weight"):
        _initialise_from(model, str(other))


@pytest.mark.parametrize(
    "values, words",
    [
        ({"pooling": "pooled", "inputs": "nominal", "max_rotation_deg": 0.0}, "pooling: pooled needs"),
        ({"pooling": "pooled", "inputs": "calibrated"}, "max_rotation_deg: 5.0"),
        ({"pooling": "mean"}, "pooling must be"),
    ],
)
def test_a_pooled_model_needs_calibrated_inputs_and_no_rotation(values, words):
    with pytest.raises(ConfigError, match=words):
        config_from_dict({"model": {"warp": "depth", **values}}, "any.yaml")


@pytest.mark.parametrize(
    "values, words",
    [
        ({"rig": "ring"}, "rig must be"),
        ({"cameras": [1, 4]}, "cameras must be"),
        ({"hfov_range": [200, 150]}, "hfov_range must be"),
        ({"tri_share": 1.5}, "tri_share"),
    ],
)
def test_random_rig_keys_are_checked(values, words):
    with pytest.raises(ConfigError, match=words):
        config_from_dict({"data": values}, "any.yaml")
