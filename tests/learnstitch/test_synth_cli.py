"""``learnstitch synth`` on disk: resume, atomic samples, refusal to mix configs; the datasets."""

import json
import multiprocessing

import numpy as np
import pytest
import torch

import rigjax
from learnstitch import FolderDataset, GeneratedDataset, load_config, synthesise
from learnstitch.cli import main
from learnstitch.data import generate
from learnstitch.data.datasets import InfiniteGeneratedDataset
from rigjax.errors import ConfigError

TINY = "data:\n  fisheye_size: 32\n  pano_width: 64\n  distance: 0.4\n"


@pytest.fixture()
def tiny(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    return path


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_rerun_resumes_and_renders_the_same_samples(tmp_path, tiny, capsys):
    out = tmp_path / "out"
    assert main(["synth", "--config", str(tiny), "--out", str(out), "--num", "2", "--quiet"]) == 0
    first = _files(out / "train")
    assert main(["synth", "--config", str(tiny), "--out", str(out), "--num", "3", "--quiet", "--preview"]) == 0
    assert "1 written, 2 already there" in capsys.readouterr().out
    after = _files(out / "train")
    assert {k: v for k, v in after.items() if k.startswith(("000000/", "000001/"))} == first  # untouched
    assert (out / "preview_train.png").stat().st_size > 0
    # The same samples rendered in a fresh folder, two workers: the same bytes.
    other = tmp_path / "other"
    assert main(["synth", "--config", str(tiny), "--out", str(other), "--num", "3", "--workers", "2", "--quiet"]) == 0
    assert _files(other / "train") == after


def test_a_crash_leaves_no_half_written_sample_and_the_next_run_completes(tmp_path, tiny, monkeypatch):
    config = load_config(tiny).data
    out = tmp_path / "out"
    real = generate.make_sample

    def crash_on_third(cfg, seed):
        if seed == 2:
            raise KeyboardInterrupt  # as if the user pressed Ctrl-C while sample 2 rendered
        return real(cfg, seed)

    monkeypatch.setattr(generate, "make_sample", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        synthesise(config, out, num=4, progress=False)
    names = sorted(p.name for p in (out / "train").iterdir())
    assert names == ["000000", "000001"]
    # A run killed while writing (SIGKILL: no clean-up) leaves a partial folder behind.
    (out / "train" / ".partial-000002-x").mkdir()
    (out / "train" / ".partial-000002-x" / "fisheye_0.png").write_bytes(b"truncated")
    monkeypatch.setattr(generate, "make_sample", real)
    report = synthesise(config, out, num=4, progress=False)
    assert (report.written, report.already_done, report.partial_removed) == (2, 2, 1)
    assert sorted(p.name for p in (out / "train").iterdir()) == ["000000", "000001", "000002", "000003"]


def test_a_folder_of_another_config_is_refused_and_left_untouched(tmp_path, tiny, capsys):
    out = tmp_path / "out"
    assert main(["synth", "--config", str(tiny), "--out", str(out), "--num", "1", "--quiet"]) == 0
    before = _files(out)
    other = tmp_path / "other.yaml"
    other.write_text(TINY.replace("distance: 0.4", "distance: 0.2"))
    assert main(["synth", "--config", str(other), "--out", str(out), "--num", "2", "--quiet"]) == 2
    assert "holds samples of another data config ('tiny'; distance: 0.4 there, 0.2 now)" in capsys.readouterr().err
    assert _files(out) == before


def test_a_non_empty_folder_without_manifest_is_refused(tmp_path, tiny):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(ConfigError, match="not empty and has no manifest.json"):
        synthesise(load_config(tiny).data, tmp_path / "photos", num=1, progress=False)


def test_bad_config_is_reported_with_the_file_and_key(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text("data:\n  fisheye: 32\n")
    assert main(["synth", "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    assert "bad.yaml: data: unknown key 'fisheye' (allowed: fisheye_size" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_datasets_from_disk_and_generated_agree(tmp_path, tiny):
    config = load_config(tiny).data
    synthesise(config, tmp_path / "out", split="test", num=2, progress=False)
    disk = FolderDataset(tmp_path / "out", "test")
    generated = GeneratedDataset(config, "test", length=2)
    assert len(disk) == len(generated) == 2
    for k in range(2):
        a, b = disk[k], generated[k]
        assert a["seed"] == b["seed"] == 1_000_000_000 + k
        assert (
            a["inputs"].shape == (3, 3, 32, 64) and a["masks"].shape == (3, 32, 64) and a["pano"].shape == (3, 32, 64)
        )
        # PNG keeps 8 bits; unwarping is a convex combination, so the difference stays within half a step.
        assert (a["pano"] - b["pano"]).abs().max() <= 0.5 / 255 + 1e-6
        assert (a["inputs"] - b["inputs"]).abs().max() <= 0.5 / 255 + 1e-6
        assert torch.all(a["inputs"][a["masks"][:, None].expand_as(a["inputs"]) == 0] == 0)  # nothing outside a lens
    stream = iter(InfiniteGeneratedDataset(config, "test"))
    assert torch.equal(next(stream)["pano"], generated[0]["pano"])
    assert torch.equal(next(stream)["pano"], generated[1]["pano"])


def test_the_written_project_and_metadata_describe_the_rendered_rig(tmp_path, tiny):
    config = load_config(tiny).data
    synthesise(config, tmp_path / "out", num=1, progress=False)
    folder = tmp_path / "out" / "train" / "000000"
    project = rigjax.load_project(folder / "rig.pto")
    meta = json.loads((folder / "sample.json").read_text())
    assert [image.filename for image in project.images] == ["fisheye_0.png", "fisheye_1.png", "fisheye_2.png"]
    np.testing.assert_allclose([image.yaw for image in project.images], meta["cameras"]["yaw"], atol=1e-9)
    nominal = np.array([0.0, 120.0, -120.0])
    assert np.all(np.abs(np.array(meta["cameras"]["yaw"]) - nominal) <= config.angle_jitter_deg)
    np.testing.assert_allclose(np.linalg.norm(meta["centres_m"], axis=1), config.distance)
    depth = np.load(folder / "depth.npy")
    assert depth.shape == (32, 64) and np.isinf(depth).any() and np.nanmin(depth) > 0.0


def test_an_out_that_is_a_file_is_refused(tmp_path, tiny, capsys):
    (tmp_path / "notes.txt").write_text("x")
    assert main(["synth", "--config", str(tiny), "--out", str(tmp_path / "notes.txt"), "--num", "1", "--quiet"]) == 2
    assert "notes.txt: is a file; --out names the folder the samples go to" in capsys.readouterr().err


def test_a_run_killed_before_the_manifest_rename_is_finished_by_the_next(tmp_path, tiny):
    out = tmp_path / "out"
    out.mkdir()
    (out / "manifest.json.partial").write_text('{"format": 2, "da')  # cut short by the kill
    report = synthesise(load_config(tiny).data, out, num=1, progress=False)
    assert report.written == 1 and (out / "manifest.json").is_file()
    assert not (out / "manifest.json.partial").exists()


def test_rendering_in_process_leaves_the_callers_thread_count(tmp_path, tiny):
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        synthesise(load_config(tiny).data, tmp_path / "out", num=1, progress=False)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_rendering_workers_run_jax_on_the_cpu_with_one_torch_thread(monkeypatch):
    # Every worker's JAX on a GPU would claim most of its memory; the maps are small.
    monkeypatch.delenv("JAX_PLATFORMS", raising=False)
    probe = "(__import__('jax').config.jax_platforms, __import__('torch').get_num_threads())"
    with multiprocessing.get_context("spawn").Pool(1, initializer=generate._worker_init) as pool:
        assert pool.apply(eval, (probe,)) == ("cpu", 1)
    # A platform the user names is kept.
    monkeypatch.setenv("JAX_PLATFORMS", "cpu,")
    with multiprocessing.get_context("spawn").Pool(1, initializer=generate._worker_init) as pool:
        assert pool.apply(eval, (probe,))[0] == "cpu,"
