"""``rigjax optimise`` and its YAML configs."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import rigjax
from rigjax import synthetic
from rigjax.cli import main
from rigjax.optimiser.schedule import parse_schedule

CONFIGS = Path(__file__).parents[2] / "configs" / "rig"


@pytest.fixture
def start_pto(tmp_path):
    truth = synthetic.cube_rig(orientation_jitter_deg=3.0, seed=21)
    truth = synthetic.control_points_from_truth(truth, 1500, noise_px=0.5, seed=22)
    start = synthetic.perturb(truth, seed=23)
    path = tmp_path / "start.pto"
    start.save(path)
    return path, truth


def test_cli_optimises_and_writes_the_project(start_pto, tmp_path, capsys):
    path, truth = start_pto
    out = tmp_path / "out.pto"
    code = main(["optimise", str(path), "-o", str(out), "--config", str(CONFIGS / "optimise.yaml")])
    printed = capsys.readouterr().out
    assert code == 0
    assert printed.splitlines()[0].split()[:3] == ["stage", "status", "params"]
    assert [line.split()[0] for line in printed.splitlines()[1:3]] == ["YPR", "VBYPR"]
    optimised = rigjax.load_project(out)
    assert len(optimised.control_points) == len(truth.control_points)
    floor = rigjax.evaluate(truth).rms
    assert abs(rigjax.evaluate(optimised).rms - floor) < 0.05 * floor
    assert "#hugin_optimizerMasterSwitch 0" in out.read_text()


def test_optimise_job_returns_what_the_command_prints_and_writes(start_pto, tmp_path, capsys):
    # The library function under the command: the same lines, file and status, and its result is
    # the written project's (without pruning: the plain optimise of the same config).
    path, _ = start_pto
    config = rigjax.OptimiseConfig("YPR,VBYPR", prune=None)
    done = rigjax.optimise_job(rigjax.OptimiseJob(path, tmp_path / "job.pto", config))
    assert done.status == 0 and done.written == (str(tmp_path / "job.pto"),)
    assert main(["optimise", str(path), "-o", str(tmp_path / "cli.pto"), "--no-prune"]) == 0
    printed = capsys.readouterr().out.replace("cli.pto", "job.pto").splitlines()
    lines = "\n".join(done.lines).splitlines()  # the stage table's times differ run to run: the rest is equal
    assert len(printed) == len(lines) and printed[0] == lines[0] and printed[-1] == lines[-1]
    assert lines[-1].startswith("final rms ") and lines[-1].endswith(f"wrote {tmp_path / 'job.pto'}")
    expected = rigjax.optimise(rigjax.load_project(path), config)
    assert done.result.rms == pytest.approx(expected.rms, rel=1e-9)
    assert rigjax.load_project(tmp_path / "job.pto").images[1].yaw == pytest.approx(
        expected.project.images[1].yaw, abs=1e-9
    )


def test_a_lens_off_nominal_is_neither_a_crawl_nor_a_failure(tmp_path, capsys):
    # A cube rig whose true hfov is 126 against the nominal 120, 0.5 px noise, no wrong matches,
    # the defaults (pruning's robust first round). Its YPR stage, with the lens held wrong, took
    # 92 of its 100 steps to crawl from 73 to 62 px before VBYPR converged to the noise floor.
    truth = synthetic.cube_rig(hfov=126.0, b=-0.01, orientation_jitter_deg=3.0, seed=3)
    truth = synthetic.control_points_from_truth(truth, 1500, noise_px=0.5, seed=103)
    nominal = synthetic.cube_rig(hfov=120.0, b=0.0).images
    start = truth.replace(
        images=tuple(
            t.replace(yaw=n.yaw, pitch=n.pitch, roll=n.roll, hfov=120.0, b=0.0) for t, n in zip(truth.images, nominal)
        )
    )
    start.save(tmp_path / "start.pto")
    out = tmp_path / "out.pto"
    code = main(["optimise", str(tmp_path / "start.pto"), "-o", str(out)])
    rows = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines()[1:3]}
    assert code == 0
    assert rows["YPR"][1] == "converged" and int(rows["YPR"][3]) <= 20
    assert rows["VBYPR"][1] == "converged"
    optimised = rigjax.load_project(out)
    assert all(abs(image.hfov - 126.0) < 0.1 for image in optimised.images)
    floor = rigjax.evaluate(truth).rms
    assert abs(rigjax.evaluate(optimised).rms - floor) < 0.05 * floor


def test_cli_hugin_config_lands_on_the_recorded_hugin_optimum(tmp_path, capsys):
    """configs/rig/hugin.yaml is `autooptimiser -n`: the project's v lines on Hugin's objective."""
    golden = Path(__file__).parent / "data" / "golden_optimiser"
    out = tmp_path / "out.pto"
    code = main(
        ["optimise", str(golden / "linked_vabc.start.pto"), "-o", str(out), "--config", str(CONFIGS / "hugin.yaml")]
    )
    assert code == 0 and capsys.readouterr().out.splitlines()[1].split()[0] == "v-lines"
    ours, hugin = rigjax.load_project(out), rigjax.load_project(golden / "linked_vabc.hugin.pto")
    assert abs(ours.images[0].hfov - hugin.images[0].hfov) < 1e-4
    assert abs(ours.images[0].b - hugin.images[0].b) < 1e-5


def test_cli_options_override_the_config(start_pto, tmp_path, capsys):
    path, _ = start_pto
    code = main(
        [
            "optimise",
            str(path),
            "-o",
            str(tmp_path / "o.pto"),
            "--config",
            str(CONFIGS / "optimise.yaml"),
            "--schedule",
            "YPR,YPR_V",
            "--max-steps",
            "1",
        ]
    )
    printed = capsys.readouterr().out
    assert code == 3  # a stage ran out of steps
    assert [line.split()[:2] for line in printed.splitlines()[1:3]] == [["YPR", "max_steps"], ["YPR_V", "max_steps"]]


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIGS.glob("*.yaml")))
def test_shipped_configs_are_valid(name):
    config = rigjax.load_config(CONFIGS / name)
    assert parse_schedule(config.schedule)


@pytest.mark.parametrize(
    "text, message",
    [
        ("schedule: YPR\nschedul: VBYPR\n", r"cfg.yaml: unknown key 'schedul' \(allowed: schedule, pto_vars"),
        ("solver: {max_step: 3}\n", r"cfg.yaml: solver: unknown key 'max_step' \(allowed: max_steps"),
        ("solver: {max_steps: many}\n", r"cfg.yaml: solver.max_steps: expected an integer, got 'many'"),
        ("objective: hugin2\n", r"objective must be one of transfer, sphere, hugin, reprojection, got 'hugin2'"),
        ("robust: {loss: l1}\n", r"cfg.yaml: robust: loss must be one of huber, cauchy or null, got 'l1'"),
        ("robust: {loss: cauchy, scale: .nan}\n", r"cfg.yaml: robust.scale: expected a finite number, got nan"),
        ("robust: {loss: cauchy, scale: -2}\n", r"cfg.yaml: robust: scale must be a positive number of pixels, got -2"),
        ("schedule: YPR,VQYPR\n", r"cfg.yaml: stage 'VQYPR': unknown parameter letter 'Q'"),
        ("solver: {backend: scipy}\n", r"cfg.yaml: solver: backend must be one of optimistix, jaxopt, got 'scipy'"),
        ("centres: [[0, 0, 1], [1, 0]]\n", r"cfg.yaml: centres\[1\]: expected a list of 3 values, got \[1, 0\]"),
        ("objective: reprojection\npriors: {v: 0}\n", r"cfg.yaml: priors: v must be a positive standard deviation"),
        (
            "objective: reprojection\npriors: {q: 1}\n",
            r"cfg.yaml: priors: unknown key 'q' \(allowed: v, a, b, c, d, e, y, p, r, x\)",
        ),
        ("priors: {v: 1.0}\n", r"cfg.yaml: priors apply to objective reprojection only, not 'transfer'"),
        (
            "schedule: YPR,VYPRX\n",
            r"cfg.yaml: schedule 'YPR,VYPRX' estimates centres \(X\): set objective reprojection",
        ),
        ("objective: reprojection\nschedule: YPR,VYPRX\n", r"estimates centres \(X\): give priors.x"),
        ("- a list\n", r"cfg.yaml: expected a mapping"),
        ("schedule: [unclosed\n", r"cfg.yaml: not valid YAML"),
    ],
)
def test_bad_configs_name_the_key(tmp_path, text, message):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(text)
    with pytest.raises(rigjax.ConfigError, match=message):
        rigjax.load_config(cfg)


def test_cli_reports_bad_input(start_pto, tmp_path, capsys):
    path, _ = start_pto
    code = main(["optimise", str(path), "-o", str(tmp_path / "o.pto"), "--schedule", "YPR,VQ"])
    assert code == 2 and "unknown parameter letter 'Q'" in capsys.readouterr().err
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("anchors: 1\n")
    code = main(["optimise", str(path), "-o", str(tmp_path / "o.pto"), "--config", str(cfg)])
    assert code == 2 and f"{cfg}: unknown key 'anchors'" in capsys.readouterr().err
    assert not (tmp_path / "o.pto").exists()


def test_a_second_process_solving_the_same_structure_does_not_trace_the_solve(start_pto, tmp_path):
    """JAX logs every function it traces (``JAX_LOG_COMPILES``): the first process traces one solve
    for both stages of the default schedule and every pruning round, robust or not (the metrics
    before and after inside it), a second one on the same project loads its export instead, and
    writes the same project. Python lists every module it imports (``PYTHONPROFILEIMPORTTIME``):
    the second process does not import the solver."""
    path, _ = start_pto
    cache = tmp_path / "cache"
    env = dict(os.environ, RIGJAX_CACHE_DIR=str(cache), JAX_LOG_COMPILES="1", PYTHONPROFILEIMPORTTIME="1")
    exe = str(Path(sys.executable).with_name("rigjax"))
    traced, solver_imported = [], []
    for run in (1, 2):
        out = tmp_path / f"o{run}.pto"
        done = subprocess.run([exe, "optimise", str(path), "-o", str(out)], env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        traced.append(re.findall(r"Finished tracing (\w+) for jit", done.stderr))
        solver_imported.append(re.search(r"\| +optimistix$", done.stderr, re.MULTILINE) is not None)
    assert traced[0].count("solve_stage") == 1  # YPR and VBYPR, robust and least squares
    assert "solve_stage" not in traced[1] and "point_metrics" not in traced[1], traced[1]
    assert solver_imported == [True, False]
    assert (tmp_path / "o1.pto").read_bytes() == (tmp_path / "o2.pto").read_bytes()
    exports = sorted(path.name.split("-")[0] for path in (cache / "exports").glob("*.jaxexport"))
    assert exports == ["solve"]  # no program of its own for the metrics
