"""The README's Python example runs as written (on the demo's project)."""

from __future__ import annotations

import re
from pathlib import Path

from rigjax import synthetic

README = Path(__file__).parents[1] / "README.md"


def test_readme_python_example_runs(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks
    monkeypatch.chdir(tmp_path)
    (tmp_path / "build" / "demo").mkdir(parents=True)
    # What `make demo` writes there: a calibrated 6-camera ring of 1440x1080 fisheyes with control points.
    synthetic.control_points_from_truth(synthetic.ring_rig(orientation_jitter_deg=2.0, seed=1), 400, seed=2).save(
        "build/demo/rig.pto"
    )
    namespace: dict = {}
    exec(compile(blocks[0], str(README), "exec"), namespace)
    assert namespace["valid"].shape == (3,) and (tmp_path / "turned.pto").exists()


def test_readme_learnstitch_example_runs(tmp_path, monkeypatch):
    import shutil

    import learnstitch

    block = next(b for b in re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S) if "learnstitch" in b)
    shutil.copytree(README.parent / "configs", tmp_path / "configs")
    monkeypatch.chdir(tmp_path)
    config = learnstitch.load_config("configs/stitch/cpu_tiny_d04.yaml").data
    learnstitch.synthesise(config, "data/tiny04", num=2, progress=False)
    namespace: dict = {}
    exec(compile(block, str(README), "exec"), namespace)
    assert namespace["batch"]["inputs"].shape == (2, 3, 3, 128, 256)


def test_readme_stitching_network_example_runs(tmp_path, monkeypatch):
    """The network's Python API block, with configs/stitch/cpu_tiny_d02.yaml shrunk to seconds."""
    import shutil

    import yaml

    block = next(b for b in re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S) if "learnstitch.train(" in b)
    shutil.copytree(README.parent / "configs", tmp_path / "configs")
    path = tmp_path / "configs" / "stitch" / "cpu_tiny_d02.yaml"
    values = yaml.safe_load(path.read_text())
    values["data"].update(fisheye_size=48, pano_width=64)
    values["model"].update(widths=[4, 8, 8], regressor_width=8, head_width=4, homographies=2)
    values["train"].update(samples=2, batch_size=2, epochs=1, data_dir="data/tiny", tensorboard=False)
    values["evaluate"].update(workers=1)
    path.write_text(yaml.safe_dump(values))
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(block, str(README), "exec"), namespace)
    assert namespace["pano"].shape == (3, 32, 64) and namespace["report"].final_step == 1
    assert len(namespace["result"].samples) == 8
