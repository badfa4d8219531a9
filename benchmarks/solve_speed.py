#!/usr/bin/env python3
"""Benchmark: one staged solve (YPR,VBYPR) of a 6-camera rig with ~1000 control points.

Rows, all in one run on the same problems:
* rigjax ``optimise``, warm (compiled), median over different starts; and the first call
  (compilation included);
* scipy ``least_squares(method="lm")`` (MINPACK) on the identical residual function (rigjax's,
  jitted), staged the same way: with MINPACK's forward-difference Jacobian (as Hugin's libpano13
  does it), and with rigjax's analytic Jacobian;
* ``optimise_batch`` over many starts, vmapped and in threads, time per problem.

    python benchmarks/solve_speed.py [--starts 10] [--batch 256] [--repeats 5]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from functools import partial

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
from _record import recorded
from scipy.optimize import least_squares

import rigjax
from rigjax import synthetic
from rigjax.optimiser import objective, staged
from rigjax.optimiser.problem import initial_params, prepare


def make_problem(seed: int):
    truth = synthetic.cube_rig(hfov=123.0, b=-0.01, orientation_jitter_deg=3.0, seed=0)
    truth = synthetic.control_points_from_truth(truth, 1500, noise_px=0.5, seed=1)
    return truth, synthetic.perturb(truth, angle_deg=(3, 20), hfov_offset_deg=(3, 8), b=0.0, seed=seed)


# The stage's data travel as a flat list of device arrays, converted once per stage, so that a
# callback costs little more than the residuals themselves. (With host arrays, which every call
# transfers again, the forward-difference row took 276/297 ms against 262/236 ms: six starts, two
# rounds.)
@partial(jax.jit, static_argnums=(1, 2))
def stage_residuals(params, structure, config, *leaves):
    return objective.stage_residuals(params, jax.tree_util.tree_unflatten(structure, leaves), config)


@partial(jax.jit, static_argnums=(1, 2))
def _jacobian(params, structure, config, *leaves):
    return jax.jacfwd(objective.stage_residuals)(params, jax.tree_util.tree_unflatten(structure, leaves), config)


def scipy_staged(start: rigjax.Project, jacobian: str):
    """The same stages, residuals and parameter layout, solved by MINPACK: the final rms, and how
    many times it called the residuals and the Jacobian."""
    problem = prepare(start, "YPR,VBYPR")
    cameras = problem.cameras
    calls = [0, 0]
    for _, layout in problem.stages:
        args = staged._args(problem, layout, cameras)
        leaves, structure = jax.tree_util.tree_flatten(jax.tree_util.tree_map(jnp.asarray, args))
        config = objective.stage_config(problem.config, args.slot)  # rigjax's Jacobian of this stage
        active = layout.size
        full0 = initial_params(layout, cameras)

        def embed(p):
            return jnp.asarray(np.concatenate([p, full0[active:]]))

        def fun(p):
            calls[0] += 1
            return np.asarray(stage_residuals(embed(p), structure, config, *leaves))

        def jac(p):
            calls[1] += 1
            return np.asarray(_jacobian(embed(p), structure, config, *leaves))[:, :active]

        sol = least_squares(
            fun, full0[:active], jac=jac if jacobian == "analytic" else "2-point", method="lm", xtol=1e-10, ftol=1e-12
        )
        cameras = objective.with_theta(args.base, objective.theta_from_params(embed(sol.x), args))
    return rigjax.evaluate(start.with_cameras(staged._to_host(cameras))).rms, calls


def median_times(fns, runs, repeats):
    """For each of ``fns``: the median over the runs of each run's fastest of ``repeats``, and its
    output on the last run. The solvers take turns on every run and repeat, so that the machine's
    drift (it is noisy) weighs on all of them alike."""
    best = [[float("inf")] * len(runs) for _ in fns]
    outs = [None] * len(fns)
    for r, run in enumerate(runs):
        for _ in range(repeats):
            for k, fn in enumerate(fns):
                t = time.perf_counter()
                outs[k] = fn(run)
                best[k][r] = min(best[k][r], time.perf_counter() - t)
    return [(statistics.median(times), out) for times, out in zip(best, outs)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--starts", type=int, default=10)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5, help="runs of each start per solver; its fastest counts")
    args = parser.parse_args()

    truth, first = make_problem(100)
    starts = [make_problem(seed)[1] for seed in range(args.starts)]
    floor = rigjax.evaluate(truth).rms

    t = time.perf_counter()
    rigjax.optimise(first)
    cold = time.perf_counter() - t
    jacobians = ("2-point", "analytic")
    for jacobian in jacobians:
        scipy_staged(first, jacobian)  # compile the callbacks
    (warm, result), *scipy = median_times(
        [rigjax.optimise, *(partial(scipy_staged, jacobian=jacobian) for jacobian in jacobians)], starts, args.repeats
    )
    evaluations = sum(s.evaluations for s in result.stages)  # each LM step linearises: residuals and Jacobian
    rows = [("rigjax optimise (warm)", warm, result.rms, (evaluations, evaluations))]
    for jacobian, (t_scipy, (rms, calls)) in zip(jacobians, scipy):
        rows.append((f"scipy least_squares lm, {jacobian} Jacobian", t_scipy, rms, calls))

    batch = [make_problem(1000 + seed)[1] for seed in range(args.batch)]
    batches = []
    for vectorise in (True, False):
        t = time.perf_counter()
        rigjax.optimise_batch(batch, vectorise=vectorise)
        cold_batch = time.perf_counter() - t
        t = time.perf_counter()
        results = rigjax.optimise_batch(batch, vectorise=vectorise)
        batches.append((vectorise, time.perf_counter() - t, cold_batch, sum(r.ok for r in results)))

    print(
        f"YPR,VBYPR on a 6-camera rig, {len(truth.control_points)} control points (0.5 px noise), starts 3-20 deg "
        f"off; rms at the true parameters {floor:.4f} px; {platform.machine()}, "
        f"{jax.devices()[0].platform}, jax {jax.__version__}\n"
    )
    print("| solver | median time per solve | vs rigjax | final rms px | residual / Jacobian evaluations |")
    print("|---|---|---|---|---|")
    for name, t_, rms, (residual_calls, jacobian_calls) in rows:
        print(f"| {name} | {t_ * 1e3:.0f} ms | {t_ / warm:.1f}x | {rms:.4f} | {residual_calls} / {jacobian_calls} |")
    for vectorise, batch_time, _, ok in batches:
        how = "vmapped" if vectorise else "threads"
        print(
            f"| rigjax optimise_batch, {args.batch} starts, {how} | {batch_time / args.batch * 1e3:.0f} ms per problem "
            f"({batch_time:.1f} s in all; {ok}/{args.batch} converged) | {batch_time / args.batch / warm:.1f}x | - | - |"
        )
    print(
        f"\nfirst call of optimise (compilation included): {cold:.1f} s; first optimise_batch call: "
        + ", ".join(f"{'vmapped' if v else 'threads'} {c:.1f} s" for v, _, c, _ in batches)
    )


if __name__ == "__main__":
    with recorded(__file__, __doc__, page=None if jax.default_backend() == "cpu" else "solve_speed_gpu"):
        main()
