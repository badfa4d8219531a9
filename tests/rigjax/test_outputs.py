"""Output paths are checked before the work, by both command lines (rigjax.outputs)."""

from __future__ import annotations

import re

import pytest

from rigjax import synthetic
from rigjax.cli import main
from rigjax.outputs import OutputError, check_output


@pytest.fixture
def project(tmp_path):
    rig = synthetic.control_points_from_truth(synthetic.cube_rig(seed=1), 60, noise_px=0.5, seed=2)
    path = tmp_path / "start.pto"
    rig.save(path)
    return path


@pytest.mark.parametrize(
    "output, message",
    [
        ("missing/out.pto", r"output .*missing/out\.pto: the folder .*missing does not exist"),
        (".", r"output \.: is a folder; name a file in it"),
    ],
)
def test_optimise_refuses_an_output_it_cannot_write_before_optimising(
    project, tmp_path, monkeypatch, capsys, output, message
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("rigjax.cli._enable_float64", lambda: pytest.fail("the work started"))
    assert main(["optimise", str(project), "-o", output]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rigjax optimise: error: ") and re.search(message, err), err


@pytest.mark.parametrize("name, suffix", [("pano.xyz", ".xyz"), ("pano", "(none)")])
def test_render_refuses_a_suffix_no_image_format_has(tmp_path, capsys, name, suffix):
    assert main(["render", "any.pto", "-o", str(tmp_path / name)]) == 2
    assert f"no image format for the suffix {suffix}; use .png, .jpg or .tif" in capsys.readouterr().err


def test_check_output_accepts_what_can_be_written(tmp_path):
    assert check_output(tmp_path / "a.pto") == str(tmp_path / "a.pto")
    assert check_output(tmp_path / "a.jpg", image=True) == str(tmp_path / "a.jpg")
    with pytest.raises(OutputError, match="--render .*: no image format for the suffix .pto"):
        check_output(tmp_path / "a.pto", image=True, what="--render")
