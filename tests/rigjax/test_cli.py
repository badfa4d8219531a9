"""``rigjax trafo``: pano_trafo's arguments and formats, and clear errors on bad input; ``rigjax render``
as a function; the worker set-up."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from golden import GOLDEN, load_golden

from rigjax.cli import main

PROJECT = str(GOLDEN / "cube_rig_linked.pto")


def run(argv, stdin, monkeypatch, capsys):
    monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def _parse(text):
    return np.array([[float(v) for v in line.split()] for line in text.splitlines()])


@pytest.mark.parametrize("direction", ["f", "r"])
def test_triplets_reproduce_the_golden_data(direction, monkeypatch, capsys):
    golden = load_golden("cube_rig_linked")[direction]
    stdin = "".join(f"{k} {x:.6f} {y:.6f}\n" for k, (x, y) in zip(golden.image, golden.xy_in))
    argv = ["trafo"] + (["-r"] if direction == "r" else []) + [PROJECT]
    code, out, _ = run(argv, stdin, monkeypatch, capsys)
    assert code == 0
    ours = _parse(out)
    assert ours.shape == golden.xy_out.shape
    ok = np.all(np.isfinite(ours), axis=1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(ours[ok], golden.xy_out[ok], atol=0.01)
    # Six decimals, as pano_trafo prints.
    assert all(len(v.split(".")[1]) == 6 for v in out.split()[:10])


def test_pairs_with_an_image_number(monkeypatch, capsys):
    golden = load_golden("cube_rig_linked")["f"]
    sel = golden.image == 3
    stdin = "".join(f"{x:.6f} {y:.6f}\n" for x, y in golden.xy_in[sel])
    code, out, _ = run(["trafo", PROJECT, "3"], "\n" + stdin, monkeypatch, capsys)  # blank lines are skipped
    assert code == 0
    np.testing.assert_allclose(_parse(out), golden.xy_out[sel], atol=0.01)


def test_points_without_a_position_print_nan(monkeypatch, capsys):
    # Straight behind a rectilinear camera: no image position.
    project = str(GOLDEN / "rect_landscape_abcde.pto")
    code, out, err = run(["trafo", "-r", project, "0"], "1799.5 999.5\n3799.5 999.5\n", monkeypatch, capsys)
    assert code == 0
    assert out.splitlines()[0] == "nan nan" and "nan" not in out.splitlines()[1]
    assert "1 point(s) have no image position" in err


@pytest.mark.parametrize(
    "argv, stdin, message",
    [
        (["trafo", "missing.pto"], "", r"missing\.pto: cannot read the project"),
        (["trafo", PROJECT], "0 1 nan\n", r"<stdin>:1: coordinate 'nan' is not a finite number"),
        (["trafo", PROJECT], "0 1 2\n0 1 inf\n", r"<stdin>:2: coordinate 'inf' is not a finite number"),
        (["trafo", PROJECT], "0 1\n", r"<stdin>:1: expected 'image x y', got '0 1'"),
        (["trafo", PROJECT, "2"], "1 2 3\n", r"<stdin>:1: expected 'x y', got '1 2 3'"),
        (["trafo", PROJECT], "\n9 1 2\n", r"<stdin>:2: image 9 does not exist \(the project has 6 images\)"),
        (["trafo", PROJECT], "x 1 2\n", r"<stdin>:1: image number 'x' is not an integer"),
        (["trafo", PROJECT], "0 1 2,5\n", r"<stdin>:1: coordinate '2,5' is not a number"),
        (["trafo", PROJECT, "7"], "1 2\n", r"image 7 does not exist"),
    ],
)
def test_bad_input_is_named_and_exits_non_zero(argv, stdin, message, monkeypatch, capsys):
    code, out, err = run(argv, stdin, monkeypatch, capsys)
    assert code == 2
    assert out == ""  # nothing half-printed
    assert err.startswith("rigjax trafo: error: ")
    assert len(re.findall(message, err)) == 1, err


def test_malformed_project_names_the_line(tmp_path, monkeypatch, capsys):
    bad = tmp_path / "bad.pto"
    bad.write_text((GOLDEN / "ff_landscape.pto").read_text().replace(" f3 ", " f5 "))
    code, _, err = run(["trafo", str(bad)], "0 1 2\n", monkeypatch, capsys)
    assert code == 2 and f"{bad}:8: token 'f5': unknown lens type f5" in err


def test_console_script_runs_and_persists_its_transform(tmp_path):
    exe = str(Path(sys.executable).with_name("rigjax"))
    cache = tmp_path / "cache"
    env = dict(os.environ, RIGJAX_CACHE_DIR=str(cache))
    done = subprocess.run([exe, "trafo", PROJECT, "0"], input="539.5 719.5\n", capture_output=True, text=True, env=env)
    assert done.returncode == 0 and done.stdout == "1799.500000 899.500000\n"
    assert any(cache.iterdir()), "the compiled transform was not persisted"
    done = subprocess.run([exe, "trafo", PROJECT, "0"], input="nan 1\n", capture_output=True, text=True, env=env)
    assert done.returncode == 2 and "not a finite number" in done.stderr


@pytest.mark.hugin
def test_output_matches_live_pano_trafo_text(hugin_tools):
    stdin = "".join(f"{k} {x} {y}\n" for k, x, y in [(0, 539.5, 719.5), (1, 10, 20), (4, 1000.25, 1.5), (5, 300, 1400)])
    for flag in ([], ["-r"]):
        hugin = subprocess.run(["pano_trafo", *flag, PROJECT], input=stdin, capture_output=True, text=True).stdout
        exe = str(Path(sys.executable).with_name("rigjax"))
        ours = subprocess.run([exe, "trafo", *flag, PROJECT], input=stdin, capture_output=True, text=True).stdout
        np.testing.assert_allclose(_parse(ours), _parse(hugin)[: len(_parse(ours))], atol=0.01)
        assert len(ours.splitlines()) == 4


def test_render_job_returns_what_the_command_prints_and_writes(tmp_path, capsys):
    import rigjax
    from rigjax.rendering.job import RenderJob, render_job

    project = tmp_path / "two.pto"
    project.write_text('p f2 w256 h128 v360\ni w128 h128 f2 v185 n"f0.png"\ni w128 h128 f2 v185 y180 n"f1.png"\n')
    rng = np.random.default_rng(0)
    images = []
    for k in range(2):
        images.append(str(tmp_path / f"f{k}.png"))
        rigjax.write_image(images[-1], rng.integers(0, 256, (128, 128, 3), dtype=np.uint8))
    out = tmp_path / "pano.png"
    done = render_job(RenderJob(project, out, tuple(images), width=64, blend="feather"))
    assert done.status == 0 and done.written == (str(out),) and done.pano.shape == (32, 64, 3)
    np.testing.assert_array_equal(rigjax.read_image(out), done.pano)
    assert main(["render", str(project), *images, "-o", str(out), "--width", "64", "--blend", "feather"]) == 0
    assert capsys.readouterr().out == "".join(f"{line}\n" for line in done.lines)
    assert done.lines == (f"wrote {out} (64x32, {100 * done.covered.mean():.1f}% covered)",)


def test_setup_worker_sets_what_it_is_asked_and_leaves_the_rest(monkeypatch):
    import cv2
    import jax

    from rigjax.worker import setup_worker

    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    before = cv2.getNumThreads()
    try:
        assert setup_worker(float64=True, opencv_threads=1, omp_wait_policy="PASSIVE") is None
        assert jax.config.jax_enable_x64 and cv2.getNumThreads() == 1
        assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"  # the user's choice stays
    finally:
        cv2.setNumThreads(before)
    monkeypatch.delenv("OMP_WAIT_POLICY")
    setup_worker(float64=False, omp_wait_policy="PASSIVE")
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE" and jax.config.jax_enable_x64
    with pytest.raises(ValueError, match="threads: expected a count of 1 or more, got 0"):
        setup_worker(opencv_threads=0)
