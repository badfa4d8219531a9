"""Both command lines on bad input: one ``PROG COMMAND: error:`` line naming the culprit, status 2,
no traceback (run as a user runs them, in a fresh process)."""

import shlex
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_WEIGHTS = ROOT / "learnstitch" / "weights" / "cpu_tiny_depth_d04.pt"


def _run(tmp_path: Path, package: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", f"{package}.cli", *args], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )


# name -> (command line, what the error line must name); the files they read are written by `inputs`.
CASES = {
    "rigjax trafo, missing project": ("rigjax trafo missing.pto 0", "missing.pto"),
    "rigjax optimise, unknown config key": (
        "rigjax optimise tiny.pto -o out.pto --config bad_key.yaml",
        "bad_key.yaml: unknown key 'anchors'",
    ),
    "rigjax calibrate, missing template": (
        "rigjax calibrate a.png --template no_such_rig.yaml -o o.pto",
        "no_such_rig.yaml",
    ),
    "learnstitch synth, unknown config key": ("learnstitch synth --config bad_stitch.yaml --out o", "fisheye_sise"),
    "learnstitch evaluate, missing rig template": (
        f"learnstitch evaluate --config eval.yaml --checkpoint {shlex.quote(str(SHIPPED_WEIGHTS))} --out o --quiet",
        "no_such_rig.yaml",
    ),
    "learnstitch evaluate, unknown --data key": (
        f"learnstitch evaluate --config {ROOT}/configs/stitch/cpu_tiny_depth_d04.yaml "
        f"--checkpoint {shlex.quote(str(SHIPPED_WEIGHTS))} --out o --quiet --data gain=0",
        "--data: unknown key 'gain'",
    ),
    "learnstitch curves, not a run": (
        "learnstitch curves empty_run -o c.png",
        "no metrics.jsonl or validation.jsonl in empty_run",
    ),
    "learnstitch stitch, calibrated model without its rig": (
        f"learnstitch stitch f0.png f1.png f2.png --checkpoint {shlex.quote(str(SHIPPED_WEIGHTS))} -o p.png",
        "pass the calibrated cameras (learnstitch stitch --rig rig.pto",
    ),
    "learnstitch stitch, a rig of one image": ("learnstitch stitch --rig tiny.pto -o p.png", "tiny.pto: 1 image;"),
    "learnstitch stitch, a rig's missing image": ("learnstitch stitch --rig gone.pto -o p.png", "gone.pto:3 (image 1)"),
    "learnstitch stitch, an image of another size than its i line": (
        "learnstitch stitch --rig size.pto -o p.png",
        "f1.png: 128 x 128 pixels, but size.pto:3 (image 1) is 128 x 100",
    ),
    "learnstitch stitch, a lens rigjax does not model": ("learnstitch stitch --rig lens.pto -o p.png", "lens.pto:2"),
    "learnstitch stitch, missing image": (
        "learnstitch stitch a.png b.png c.png --checkpoint missing.pt -o p.png",
        "a.png",
    ),
}


@pytest.fixture()
def inputs(tmp_path: Path) -> Path:
    """A folder with the bad inputs the cases name."""
    (tmp_path / "bad_key.yaml").write_text("schedule: YPR\nanchors: 1\n")
    (tmp_path / "bad_stitch.yaml").write_text("data:\n  fisheye_sise: 32\n")
    stitch_config = (ROOT / "configs" / "stitch" / "cpu_tiny_depth_d04.yaml").read_text()
    (tmp_path / "eval.yaml").write_text(
        stitch_config.replace("evaluate:\n", "evaluate:\n  calibrate_template: no_such_rig.yaml\n")
    )
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.zeros((128, 128, 3), np.uint8))
    (tmp_path / "tiny.pto").write_text('p f2 w360 h180 v360\ni w100 h100 f0 v90 y0 p0 r0 n"a.png"\n')
    two = 'p f2 w256 h128 v360\ni w128 h128 f2 v185 n"f0.png"\ni w128 h128 f2 v185 y180 n"f1.png"\n'
    (tmp_path / "gone.pto").write_text(two.replace("f1.png", "missing.png"))
    (tmp_path / "size.pto").write_text(two.replace("h128 f2 v185 y180", "h100 f2 v185 y180"))
    (tmp_path / "lens.pto").write_text(two.replace("w128 h128 f2", "w128 h128 f7", 1))
    return tmp_path


@pytest.mark.parametrize("name", CASES)
def test_bad_input_ends_in_one_error_line(inputs, name):
    command_line, culprit = CASES[name]
    package, command, *args = shlex.split(command_line)
    done = _run(inputs, package, command, *args)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{package} {command}: error: "), done.stderr
    assert culprit in lines[0]
