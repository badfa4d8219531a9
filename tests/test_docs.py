"""Every code block of the README and of docs/ is checked against the code.

- ``python`` blocks run as written, a file's blocks one after another in one namespace, in a
  folder that holds what they read: the demo's project, rendered images, a synthetic data folder
  and the shipped configs (the training config shrunk to seconds);
- ``yaml`` blocks load through the loader of what they configure (a rig template, a learnstitch
  config or an optimiser config), so a renamed or removed key fails here;
- ``sh`` blocks: every ``rigjax`` and ``learnstitch`` command parses with the command line's own
  parser, so a renamed command or option fails here.
"""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import jax
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _blocks(path: Path, language: str) -> list[str]:
    """The bodies of the file's fenced code blocks in ``language``, in order."""
    blocks, lang, body = [], None, []
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            if lang is None:
                lang, body = line[3:].strip(), []
            else:
                if lang == language:
                    blocks.append("\n".join(body) + "\n")
                lang = None
        elif lang is not None:
            body.append(line)
    return blocks


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def test_the_readme_is_for_a_new_user():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 130, "the README is an entry: what it is, the two commands, examples, where to read on"
    assert not [line for line in lines if len(line) > 200], "tables and long figures belong in docs/"


def test_docs_links_point_at_files():
    missing = []
    for path in DOCS:
        for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", path.read_text()):
            if not (path.parent / target).exists():
                missing.append(f"{_name(path)}: {target}")
    assert not missing, missing


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A folder with what the docs' examples read, as `make demo` and `learnstitch synth` leave it."""
    import learnstitch
    from rigjax import synthetic

    work = tmp_path_factory.mktemp("docs")
    shutil.copytree(ROOT / "configs", work / "configs")
    (work / "build" / "demo").mkdir(parents=True)
    # The demo's calibrated 6-camera ring of 1440x1080 fisheyes, with control points.
    truth = synthetic.ring_rig(orientation_jitter_deg=2.0, seed=1)
    synthetic.control_points_from_truth(truth, 400, seed=2).save(work / "build" / "demo" / "rig.pto")
    # Images of such a ring, at half the demo's size, for the calibration examples.
    from rigjax import write_image

    half = synthetic.ring_rig(orientation_jitter_deg=2.0, seed=1, width=720, height=540)
    images = synthetic.render_images(half, synthetic.procedural_environment(2048, seed=0), noise_std=2.0, seed=0)
    for k, image in enumerate(images):
        write_image(work / f"cam{k}.png", image)
    # The demo's full-resolution rig (its images and calibrated rig.pto), at 64 pixels.
    from learnstitch.demo import fullres_demo

    fullres_demo(work / "build" / "demo" / "fullres", size=64)
    # The demo's dual-fisheye clip, its truth standing in for the calibration `make demo` writes.
    from learnstitch.demo import video_demo

    video_demo(work / "build" / "demo" / "video", size=64, frames=4)
    shutil.copy(work / "build" / "demo" / "video" / "truth.pto", work / "build" / "demo" / "video" / "rig.pto")
    # Two training samples for the dataset example.
    data = learnstitch.load_config(work / "configs" / "stitch" / "cpu_tiny_d04.yaml").data
    learnstitch.synthesise(data, work / "data" / "tiny04", num=2, progress=False)
    # The training examples' configs, shrunk to a step of two tiny samples.
    for name, model in (
        ("cpu_tiny_d02", {"homographies": 2}),
        ("cpu_tiny_depth_d04", {"depth_planes": 4}),
    ):
        path = work / "configs" / "stitch" / f"{name}.yaml"
        values = yaml.safe_load(path.read_text())
        values["data"].update(fisheye_size=48, pano_width=64)
        values["model"].update(widths=[4, 8, 8], regressor_width=8, head_width=4, **model)
        values["train"].update(
            samples=2, batch_size=2, epochs=1, data_dir=f"data/{name}", tensorboard=False, validate_every=0
        )
        values["evaluate"].update(workers=1)
        path.write_text(yaml.safe_dump(values))
    return work


# What each file's examples write: they ran to the end and did their work.
WRITES = {
    "README.md": ["optimised.pto", "pano.mp4", "runs/tiny/model.pt", "runs/tiny/eval/metrics.json"],
    "docs/rigjax/guide.md": ["turned.pto", "adjusted.pto", "calibrated.pto", "rig.pto", "pano.jpg"],
    "docs/learnstitch/guide.md": ["runs/tiny/model.pt", "build/guide/batch/clip.mp4"],
}


@pytest.fixture
def process_settings_restored(monkeypatch):
    """The examples set up their process as a user's script does (``rigjax.setup_worker``: the
    compilation cache and exports, OpenCV's threads); undone afterwards, so that the worker's later
    tests run without them."""
    import cv2
    from jax.experimental.compilation_cache import compilation_cache

    import rigjax.compiled

    monkeypatch.setattr(rigjax.compiled, "_exports", rigjax.compiled._exports)
    settings = {name: getattr(jax.config, name) for name in rigjax.compiled.CACHE_SETTINGS}
    threads = cv2.getNumThreads()
    yield
    for name, value in settings.items():
        jax.config.update(name, value)
    compilation_cache.reset_cache()  # the cache read its folder once; it reads the setting again
    cv2.setNumThreads(threads)


@pytest.mark.parametrize("path", [p for p in DOCS if _blocks(p, "python")], ids=_name)
@pytest.mark.usefixtures("process_settings_restored")
def test_python_blocks_run(path, workdir, monkeypatch):
    monkeypatch.chdir(workdir)
    shutil.rmtree(workdir / "runs", ignore_errors=True)  # each file's examples train from scratch
    for name in WRITES[_name(path)]:
        (workdir / name).unlink(missing_ok=True)
    namespace: dict = {"__name__": "__docs__"}
    for k, block in enumerate(_blocks(path, "python")):
        exec(compile(block, f"{_name(path)} python block {k}", "exec"), namespace)
    assert all((workdir / name).exists() for name in WRITES[_name(path)])


def _load_yaml_block(text: str, where: str):
    import learnstitch
    import rigjax

    data = yaml.safe_load(text)
    if "rig" in data:
        return rigjax.template_from_dict(data, where)
    if {"data", "model", "loss", "train", "evaluate", "render"} & set(data):
        return learnstitch.config_from_dict(data, where)
    return rigjax.config_from_dict(data, where)


YAML_BLOCKS = [(p, k) for p in DOCS for k, _ in enumerate(_blocks(p, "yaml"))]


@pytest.mark.parametrize("path, k", YAML_BLOCKS, ids=[f"{_name(p)}-{k}" for p, k in YAML_BLOCKS])
def test_yaml_blocks_load(path, k):
    assert _load_yaml_block(_blocks(path, "yaml")[k], f"{_name(path)} yaml block {k}") is not None


def _commands(text: str) -> list[tuple[str, list[str]]]:
    """``(program, arguments)`` of every rigjax or learnstitch command in a shell block."""
    out = []
    for line in text.replace("\\\n", " ").splitlines():
        line = line.split(" | ")[-1]  # the command a pipe feeds
        words = shlex.split(line, comments=True)
        for program in ("rigjax", "learnstitch"):
            for start in (program, f"{program}.cli"):  # `torchrun ... -m learnstitch.cli train ...`
                if start in words:
                    out.append((program, words[words.index(start) + 1 :]))
                    break
    return out


SH_COMMANDS = [(p, program, args) for p in DOCS for block in _blocks(p, "sh") for program, args in _commands(block)]


def test_the_docs_show_commands_of_both_programs():
    assert {program for _, program, _ in SH_COMMANDS} == {"rigjax", "learnstitch"}
    assert len(SH_COMMANDS) > 20


@pytest.mark.parametrize(
    "path, program, args", SH_COMMANDS, ids=[f"{_name(p)}: {prog} {' '.join(a)[:60]}" for p, prog, a in SH_COMMANDS]
)
def test_sh_commands_parse(path, program, args):
    import learnstitch.cli
    import rigjax.cli

    parser = {"rigjax": rigjax.cli, "learnstitch": learnstitch.cli}[program].build_parser()
    parser.parse_args(args)
