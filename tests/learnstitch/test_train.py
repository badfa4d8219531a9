"""Training runs: checkpoints, bit-for-bit resume, NaN handling, config mismatches, data parallel,
evaluation and stitching, on a tiny config (48-px fisheyes, 64 x 32 panorama)."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest
import torch
from torch.utils.data import Dataset

import rigjax
from learnstitch import cli
from learnstitch.baselines import depth_oracle_stitch, psnr, rotation_only_stitch
from learnstitch.checkpoint import load_checkpoint, load_model, save_checkpoint
from learnstitch.config import config_as_dict, config_from_dict
from learnstitch.data.datasets import FolderDataset
from learnstitch.data.sample import make_sample
from learnstitch.data.store import SPLIT_SEED_BASE, write_png
from learnstitch.data.visibility import sight_lines
from learnstitch.demo import demo
from learnstitch.evaluation import data_with, evaluate, parse_overrides
from learnstitch.inference import RIG_MODEL, SHIPPED_MODEL, read_fisheyes, stitch_fisheyes
from learnstitch.network.model import StitchNet
from learnstitch.training import TrainingError, resolve_device, train
from rigjax.errors import ConfigError
from rigjax.rendering.images import ImageError

TINY = {
    "data": {"fisheye_size": 48, "pano_width": 64},
    "model": {"homographies": 2, "widths": [4, 8, 8], "regressor_width": 8, "head_width": 4},
    "train": {
        "seed": 3,
        "epochs": 2,
        "batch_size": 2,
        "samples": 6,
        "checkpoint_every": 2,
        "log_every": 1,
        "image_every": 3,
        "lr": 0.01,
    },
    "evaluate": {"samples": 2, "workers": 1, "examples": 1},
}


def tiny(tmp_path: Path, **train) -> object:
    values = json.loads(json.dumps(TINY))
    values["train"].update({"data_dir": str(tmp_path / "data"), **train})
    return config_from_dict(values, "tiny.yaml")


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    """Six training samples on disk, shared by the tests of this module."""
    root = tmp_path_factory.mktemp("stitch")
    config = tiny(root)
    train(config, root / "warmup", progress=False)  # also renders train.data_dir
    return root


@pytest.mark.parametrize(
    "section, values, message",
    [
        (
            "model",
            {"homographys": 5},
            r"x.yaml: model: unknown key 'homographys' \(allowed: warp, inputs, homographies",
        ),
        ("model", {"widths": [16, "32"]}, r"x.yaml: model.widths\[1\]: expected an integer, got '32'"),
        ("model", {"widths": [4] * 8}, "pano_width 256 x 128: both must be multiples of the encoder.s stride 256"),
        ("loss", {"pixel": "vgg"}, "x.yaml: loss: pixel must be 'l1' or 'perceptual', got 'vgg'"),
        ("train", {"lr": "fast"}, r"x.yaml: train.lr: expected a number, got 'fast'"),
        ("train", {"lr": float("inf")}, r"x.yaml: train.lr: expected a finite number, got inf"),
        ("train", {"grad_clip": float("nan")}, r"x.yaml: train.grad_clip: expected a finite number, got nan"),
        ("train", {"lr_schedule": "step"}, "lr_schedule must be 'constant' or 'cosine'"),
        ("train", {"tensorboard": "yes"}, r"train.tensorboard: expected true or false"),
        ("evaluate", {"workers": 0}, "x.yaml: evaluate: samples and workers must be >= 1"),
    ],
)
def test_bad_training_configs_name_the_key(section, values, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict({section: values}, "x.yaml")


class Crashing(Dataset):
    """The run's data, with a crash (as from a killed worker) at the ``at``-th item read."""

    def __init__(self, dataset: Dataset, at: int):
        self.dataset, self.at, self.reads = dataset, at, 0

    def __len__(self):
        return len(self.dataset)

    def __getitem__(self, index):
        self.reads += 1
        if self.reads == self.at:
            raise RuntimeError("simulated crash")
        return self.dataset[index]


class Poisoned(Dataset):
    """Item ``bad`` has a NaN ground truth."""

    def __init__(self, dataset: Dataset, bad: int):
        self.dataset, self.bad = dataset, bad

    def __len__(self):
        return len(self.dataset)

    def __getitem__(self, index):
        item = dict(self.dataset[index])
        if index == self.bad:
            item["pano"] = torch.full_like(item["pano"], float("nan"))
        return item


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return load_checkpoint(path)["model"]


def test_a_cuda_device_named_without_an_index_is_the_processs_own():
    # torch.cuda.set_device refuses a device without an index, which `train.device: cuda` names.
    assert resolve_device("cuda", 2) == torch.device("cuda", 2)
    assert resolve_device("cuda:1", 2) == torch.device("cuda", 1)
    assert resolve_device("cpu", 2) == torch.device("cpu")
    with pytest.raises(ConfigError, match="train.device: not a torch device: 'gpu'"):
        resolve_device("gpu")


def test_a_killed_and_resumed_run_ends_with_the_same_weights(data_dir, tmp_path):
    config = tiny(data_dir, validate_every=2, validate_samples=1)
    dataset = FolderDataset(data_dir / "data", "train")
    straight = train(config, tmp_path / "straight", dataset=dataset, progress=False)
    assert straight.final_step == 6  # 2 epochs of 3 steps

    with pytest.raises(RuntimeError, match="simulated crash"):  # in step 4: checkpoint of step 2 on disk
        train(config, tmp_path / "killed", dataset=Crashing(dataset, at=7), progress=False)
    assert load_checkpoint(tmp_path / "killed" / "checkpoint.pt")["step"] == 2
    assert not (tmp_path / "killed" / "model.pt").exists()
    with (tmp_path / "killed" / "metrics.jsonl").open("a") as log:
        log.write('{"step": 4, "lo')  # a line the crash cut short
    resumed = train(config, tmp_path / "killed", dataset=dataset, resume=True, progress=False)
    assert (resumed.steps, resumed.final_step) == (4, 6)

    a, b = _weights(tmp_path / "straight" / "model.pt"), _weights(tmp_path / "killed" / "model.pt")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # The log has each step once, as the uninterrupted run's.
    steps = lambda run: [
        json.loads(line)["step"] for line in (tmp_path / run / "metrics.jsonl").read_text().splitlines()
    ]  # noqa: E731
    assert steps("killed") == steps("straight") == [1, 2, 3, 4, 5, 6]
    # Validation (PSNR over seen pixels, as configured and clean, gain on and off) at steps 2, 4, 6,
    # the same numbers in both runs; the learning curves drawn.
    validation = [(tmp_path / run / "validation.jsonl").read_text() for run in ("straight", "killed")]
    records = [json.loads(line) for line in validation[0].splitlines()]
    assert validation[0] == validation[1] and [r["step"] for r in records] == [2, 4, 6]
    assert set(records[0]["clean"]) == {"network", "network_gain_off", "rotation_only"}
    assert cv2.imread(str(tmp_path / "killed" / "learning_curves.png")) is not None
    assert sorted(p.name for p in (tmp_path / "straight" / "samples").iterdir()) == [
        "step_000003.png",
        "step_000006.png",
    ]
    assert any((tmp_path / "straight" / "tensorboard").glob("events.out.tfevents.*"))


def test_checkpoints_hold_only_tensors_and_plain_values(data_dir):
    state = torch.load(data_dir / "warmup" / "checkpoint.pt", weights_only=True)
    assert state["step"] == 6 and state["config"] == config_as_dict(tiny(data_dir))
    assert isinstance(state["rng"], torch.Tensor)


def test_a_nan_loss_stops_training_with_the_last_checkpoint_intact(data_dir, tmp_path):
    config = tiny(data_dir, epochs=1)
    dataset = FolderDataset(data_dir / "data", "train")
    order = torch.randperm(
        6, generator=torch.Generator().manual_seed(3 * 1_000_003)
    )  # epoch 0's order (the sampler's rule)
    with pytest.raises(
        TrainingError, match=r"step 3: the loss is nan.*checkpoint.pt \(the last good state\) is intact"
    ):
        train(config, tmp_path / "run", dataset=Poisoned(dataset, bad=int(order[4])), progress=False)
    state = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert state["step"] == 2 and all(torch.isfinite(v).all() for v in state["model"].values())


def test_without_a_data_dir_samples_are_rendered_on_the_fly(tmp_path):
    values = json.loads(json.dumps(TINY))
    values["train"].update(samples=2, epochs=1, data_dir=None, tensorboard=False)
    report = train(config_from_dict(values, "fly.yaml"), tmp_path / "run", progress=False)
    assert report.final_step == 1 and (tmp_path / "run" / "model.pt").exists() and not (tmp_path / "data").exists()


def test_a_run_is_not_overwritten_and_resumes_only_its_own_config(data_dir, tmp_path):
    config = tiny(data_dir)
    with pytest.raises(ConfigError, match="already holds a run"):
        train(config, data_dir / "warmup", progress=False)
    other = tiny(data_dir, lr=0.02)
    with pytest.raises(ConfigError, match=r"another config; these keys differ: \['train.lr'\]"):
        train(other, data_dir / "warmup", resume=True, progress=False)


def test_a_checkpoint_of_another_config_is_named(data_dir):
    values = json.loads(json.dumps(TINY))
    values["model"]["homographies"] = 3
    with pytest.raises(
        ConfigError,
        match=r"trained with another config \('tiny'\): model.homographies: 2 in the checkpoint, 3 in other",
    ):
        load_model(data_dir / "warmup" / "model.pt", config_from_dict(values, "other.yaml"))
    with pytest.raises(ConfigError, match="not a learnstitch checkpoint"):
        load_model(data_dir / "data" / "manifest.json")


def test_two_data_parallel_processes_take_the_steps_of_one(data_dir, tmp_path):
    """torchrun, 2 CPU processes (gloo), 1 item each, against the single-process run of the same batch of 2."""
    config_path = tmp_path / "tiny.yaml"
    values = config_as_dict(tiny(data_dir))
    values["train"].update(epochs=1, tensorboard=False)
    config_path.write_text(json.dumps(values))  # JSON is YAML
    env = {**os.environ, "OMP_NUM_THREADS": "1"}  # two processes on two cores
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc_per_node",
            "2",
            "-m",
            "learnstitch.cli",
            "train",
            "--config",
            str(config_path),
            "--out",
            str(tmp_path / "ddp"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    config = config_from_dict(values, str(config_path))
    train(config, tmp_path / "single", progress=False)
    a, b = _weights(tmp_path / "ddp" / "model.pt"), _weights(tmp_path / "single" / "model.pt")
    torch.manual_seed(config.train.seed)
    initial = StitchNet(config.model).state_dict()
    assert all(
        not torch.equal(a[k], initial[k]) for k in ("corners.bias", "weight_head.bias", "encoder.stages.0.0.weight")
    )
    for k in a:
        torch.testing.assert_close(a[k], b[k], atol=2e-6, rtol=1e-4)


def test_evaluation_scores_the_network_and_the_baseline_on_the_test_split(data_dir, tmp_path):
    config = tiny(data_dir)
    report = evaluate(config, data_dir / "warmup" / "model.pt", out=tmp_path / "eval", progress=False)
    # The baseline's PSNR, recomputed independently for test sample 1.
    sample = make_sample(config.data, SPLIT_SEED_BASE["test"] + 1)
    baseline, _ = rotation_only_stitch(sample.fisheyes, sample.rig, config.data)
    assert report.samples[1]["rotation_only"]["psnr_whole"] == pytest.approx(
        float(psnr(baseline, sample.pano)), abs=1e-4
    )
    assert report.samples[1]["seed"] == SPLIT_SEED_BASE["test"] + 1
    written = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert (
        written["means"] == report.means
        and "| learnstitch network | 0.2 |" in (tmp_path / "eval" / "table.md").read_text()
    )
    examples = cv2.imread(str(tmp_path / "eval" / "examples.png"))
    assert examples.shape == (32, 7 * 64, 3)  # truth; network, true-rotation, depth oracle; their errors
    assert set(report.means) == {"nominal", "rotation_only", "depth_oracle", "network", "network_gain_off"}
    assert 0.0 < report.blind_spot < 0.2 and report.blind_spot == written["blind_spot"]
    # Two worker processes (one thread each) give the same numbers, up to the summation order of kornia's SSIM.
    parallel = evaluate(config, data_dir / "warmup" / "model.pt", workers=2, progress=False)
    for a, b in zip(parallel.samples, report.samples):
        assert a["seed"] == b["seed"] and all(
            a[m] == pytest.approx(b[m], rel=1e-5) for m in ("network", "rotation_only")
        )
    # With a rig template the calibrated baseline joins. 48-pixel fisheyes give too few features:
    # calibration fails, is reported, and the nominal rig (turned onto the truth) stands in.
    values = json.loads(json.dumps(TINY))
    values["train"]["data_dir"] = str(data_dir / "data")
    values["evaluate"]["calibrate_template"] = "configs/rig/tri_fisheye.yaml"
    calibrated = evaluate(
        config_from_dict(values, "tiny.yaml"), data_dir / "warmup" / "model.pt", out=tmp_path / "cal", progress=False
    )
    assert calibrated.means["calibrated"]["failed"] == 1.0
    assert "consistent matches" in calibrated.samples[0]["calibration"]["failure"]
    assert calibrated.samples[1]["network"] == report.samples[1]["network"]
    assert "| rigjax-calibrated (from the images) | 0.2 |" in calibrated.table and "failed on 100%" in calibrated.table
    # Without control points the stitch through their depths is the calibrated stitch (all at infinity).
    assert "| rigjax-calibrated, through its points' depths | 0.2 |" in calibrated.table
    for record in calibrated.samples:
        assert record["calibrated_depth"]["psnr_whole"] == pytest.approx(record["calibrated"]["psnr_whole"], abs=1e-3)
    assert cv2.imread(str(tmp_path / "cal" / "examples.png")).shape == (32, 9 * 64, 3)
    values["evaluate"]["calibrate_template"] = "configs/rig/no_such_template.yaml"
    with pytest.raises(rigjax.RigjaxError, match="no_such_template.yaml"):
        evaluate(config_from_dict(values, "tiny.yaml"), data_dir / "warmup" / "model.pt", progress=False)


def test_evaluation_on_photometrically_clean_data(data_dir, tmp_path):
    config = tiny(data_dir)
    clean = {"gain_jitter": 0, "vignetting": 0, "noise_std": 0}
    report = evaluate(config, data_dir / "warmup" / "model.pt", out=tmp_path / "clean", data=clean, progress=False)
    # The references on the clean test sample, recomputed independently.
    data = dataclasses.replace(config.data, gain_jitter=0.0, vignetting=0.0, noise_std=0.0)
    sample = make_sample(data, SPLIT_SEED_BASE["test"] + 0)
    lines = sight_lines(sample, data)
    baseline, _ = rotation_only_stitch(sample.fisheyes, sample.rig, data)
    oracle = depth_oracle_stitch(sample.fisheyes, lines, data, baseline)
    first = report.samples[0]
    assert first["rotation_only"]["psnr_seen"] == pytest.approx(
        float(psnr(baseline, sample.pano, lines.seen)), abs=1e-4
    )
    assert first["depth_oracle"]["psnr_whole"] == pytest.approx(float(psnr(oracle, sample.pano)), abs=1e-4)
    assert json.loads((tmp_path / "clean" / "metrics.json").read_text())["data_overrides"] == clean
    assert "but gain_jitter=0, vignetting=0, noise_std=0" in report.table
    assert parse_overrides(["gain_jitter=0", "noise_std=0.5"]) == {"gain_jitter": 0, "noise_std": 0.5}
    with pytest.raises(ConfigError, match="--data 'gain_jitter': expected KEY=VALUE"):
        parse_overrides(["gain_jitter"])
    with pytest.raises(ConfigError, match="unknown key 'gain'"):
        evaluate(config, data_dir / "warmup" / "model.pt", data={"gain": 0}, progress=False)


def test_stitch_cli_writes_the_networks_panorama_and_refuses_bad_images(data_dir, tmp_path, capsys):
    model_path = data_dir / "warmup" / "model.pt"
    folder = data_dir / "data" / "train" / "000000"
    images = [str(folder / f"fisheye_{k}.png") for k in range(3)]
    assert cli.main(["stitch", *images, "--checkpoint", str(model_path), "-o", str(tmp_path / "pano.png")]) == 0
    model, config = load_model(model_path)
    expected = stitch_fisheyes(model, read_fisheyes(images)[0], config.data)
    written = torch.from_numpy(cv2.imread(str(tmp_path / "pano.png"))[..., ::-1].copy()).permute(2, 0, 1) / 255.0
    assert (written - expected).abs().max() <= 0.5 / 255 + 1e-6

    assert cli.main(["stitch", *images[:2], "--checkpoint", str(model_path), "-o", str(tmp_path / "x.png")]) == 2
    assert "expected 3 fisheye images" in capsys.readouterr().err
    # An output nothing can be written to is refused before stitching, not reported as written.
    for output, message in (("missing/pano.png", "does not exist"), ("pano.xyz", "no image format for the suffix")):
        assert cli.main(["stitch", *images, "--checkpoint", str(model_path), "-o", str(tmp_path / output)]) == 2
        assert message in capsys.readouterr().err
    with pytest.raises(ImageError, match="x.xyz: cannot write the image"):
        write_png(tmp_path / "x.xyz", expected)
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.imread(images[2])[:40, :40])
    assert (
        cli.main(["stitch", *images[:2], str(small), "--checkpoint", str(model_path), "-o", str(tmp_path / "x.png")])
        == 2
    )
    assert "small.png: 40 x 40 pixels, but" in capsys.readouterr().err
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"big_{k}.png"), cv2.resize(cv2.imread(images[k]), (64, 64)))
    big = [str(tmp_path / f"big_{k}.png") for k in range(3)]
    assert cli.main(["stitch", *big, "--checkpoint", str(model_path), "-o", str(tmp_path / "x.png")]) == 2
    assert (
        "big_0.png (and the others): 64 x 64 pixels; the model was trained on 48 x 48 fisheyes"
        in capsys.readouterr().err
    )
    assert (
        cli.main(["stitch", *images[:2], str(tmp_path / "none.png"), "--checkpoint", str(model_path), "-o", "x.png"])
        == 2
    )
    assert "none.png: no such image file" in capsys.readouterr().err


def test_the_demo_model_shipped_in_the_package_beats_the_true_rotation_stitch(tmp_path, capsys):
    """`make demo`'s stitch: the shipped network of any rig on test sample 0 of its three-fisheye
    case, against the true-rotation stitch and the depth oracle, whose PSNRs are recomputed here."""
    assert cli.main(["demo", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    rows = {
        line.split("dB")[1].strip().split()[0]: [float(v) for v in line.split("dB")[0].split("/")]
        for line in printed.splitlines()
        if " dB " in line
    }
    network, true_rotation, oracle = rows["network"], rows["true-rotation"], rows["depth"]
    config = load_model(RIG_MODEL)[1]
    data = data_with(config.data, {"rig": "tri"})  # the network of any rig's three-fisheye case
    sample = make_sample(data, SPLIT_SEED_BASE["test"])
    baseline, _ = rotation_only_stitch(sample.fisheyes, sample.rig, data)
    assert true_rotation[0] == pytest.approx(float(psnr(baseline, sample.pano)), abs=0.01)
    # whole, seen, near objects in the seams, and those above the horizon: the pole 1.0 m away in a seam
    assert len(network) == 4
    assert network[0] > true_rotation[0] + 0.5 and network[1] > true_rotation[1]
    assert oracle[1] > network[1]  # the true depth is still better
    assert network[3] >= 20.0 and network[3] > true_rotation[3] + 5.0  # the pole drawn once (issue 48)
    for name in ("network", "rotation_only", "depth_oracle", "truth", "inverse_depth"):
        assert cv2.imread(str(tmp_path / f"{name}.png")).shape == (128, 256, 3)
    # The three-fisheye rig's own model stitches the same sample.
    summary = demo(tmp_path / "tri", checkpoint=SHIPPED_MODEL)
    same = [[float(v) for v in line.split("dB")[0].split("/")] for line in summary.splitlines() if " dB " in line]
    assert same[1] == true_rotation and same[2] == oracle and same[0][1] > true_rotation[1] + 1.0


def _flip_bytes_inside_the_largest_tensor(path: Path) -> None:
    """Damage the file as a bad disk would: 64 bytes inside a tensor's record, the zip left as is."""
    import zipfile

    with zipfile.ZipFile(path) as archive:
        info = max((i for i in archive.infolist() if "/data/" in i.filename), key=lambda i: i.file_size)
    raw = bytearray(path.read_bytes())
    header = info.header_offset
    start = header + 30 + int.from_bytes(raw[header + 26 : header + 28], "little")
    start += int.from_bytes(raw[header + 28 : header + 30], "little") + info.file_size // 2
    raw[start : start + 64] = bytes(b ^ 0xFF for b in raw[start : start + 64])
    path.write_bytes(bytes(raw))


def test_a_damaged_or_incomplete_checkpoint_is_refused_naming_the_file(data_dir, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(data_dir / "warmup", run)
    config = tiny(data_dir)
    _flip_bytes_inside_the_largest_tensor(run / "checkpoint.pt")
    torch.load(run / "checkpoint.pt", weights_only=True)  # torch itself does not notice
    with pytest.raises(ConfigError, match=r"checkpoint.pt: damaged: its contents do not match the digest"):
        train(config, run, resume=True, progress=False)
    # Loadable, with a valid digest, but not a state training can resume from.
    good = load_checkpoint(data_dir / "warmup" / "checkpoint.pt")
    for change, message in (
        (lambda s: s.pop("optimiser"), r"cannot resume from it \(KeyError: 'optimiser'\)"),
        (lambda s: s.update(step="six"), r"cannot resume from it \(TypeError: step 'six' is not a step number\)"),
        (
            lambda s: s["model"].update({k: v[:1] for k, v in list(s["model"].items())[:1]}),
            r"cannot resume from it \(RuntimeError: Error\(s\) in loading state_dict",
        ),
        (lambda s: s.update(config=[1]), r"cannot resume from it: it holds no config"),
    ):
        state = {k: v for k, v in good.items() if k != "digest"}
        state["model"] = dict(state["model"])
        change(state)
        save_checkpoint(run / "checkpoint.pt", state)
        with pytest.raises(ConfigError, match=r"checkpoint.pt: " + message):
            train(config, run, resume=True, progress=False)


def test_a_sigkilled_training_process_that_rendered_its_own_data_resumes_bit_for_bit(tmp_path):
    # Each run in a fresh process renders its own data (train.data_dir empty), as a user's first run
    # does; one is killed with SIGKILL (no exception handler runs) after its first checkpoint.
    values = json.loads(json.dumps(TINY))
    values["train"].update(epochs=5, checkpoint_every=2, image_every=1000, synth_workers=1)  # 15 steps

    def command(run: str) -> list[str]:
        config = dict(values, train=dict(values["train"], data_dir=str(tmp_path / f"data_{run}")))
        path = tmp_path / f"{run}.yaml"
        path.write_text(json.dumps(config))
        return [sys.executable, "-m", "learnstitch.cli", "train", "--config", str(path), "--out", str(tmp_path / run)]

    env = dict(os.environ)
    subprocess.run(command("straight") + ["--quiet"], check=True, env=env, capture_output=True)
    killed = tmp_path / "killed"
    process = subprocess.Popen(
        command("killed") + ["--quiet"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        while not (killed / "checkpoint.pt").exists() and process.poll() is None:
            time.sleep(0.005)
        process.send_signal(signal.SIGKILL)
    finally:
        assert process.wait(timeout=60) == -signal.SIGKILL  # killed, not finished
    assert not (killed / "model.pt").exists()
    step = load_checkpoint(killed / "checkpoint.pt")["step"]
    assert 2 <= step < 15
    subprocess.run(command("killed") + ["--quiet", "--resume"], check=True, env=env, capture_output=True)
    a, b = _weights(tmp_path / "straight" / "model.pt"), _weights(killed / "model.pt")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
