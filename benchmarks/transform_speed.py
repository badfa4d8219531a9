#!/usr/bin/env python3
"""Benchmark: image -> ray -> image for 10^6 points, jitted rigjax against plain numpy.

Baseline: a vectorised numpy statement of the same formulas (full-frame fisheye with a, b, c,
d, e and yaw/pitch/roll; Newton's method for the inverse radial polynomial until every point
converges), float64. Prints a markdown table of median wall times over repeated runs, the ratio
to the baseline, and the largest difference between the two implementations.

    python benchmarks/transform_speed.py [--points N] [--repeats K]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
from _record import recorded

import rigjax

CAMERA = dict(
    projection=3,
    width=1440,
    height=1080,
    hfov=123.0,
    a=0.004,
    b=-0.03,
    c=0.01,
    d=11.0,
    e=-6.5,
    yaw=-35.0,
    pitch=25.0,
    roll=160.0,
)


# ---------------------------------------------------------------------------------------------
# The numpy baseline: the formulas of reference §1-3, written for one equidistant camera.
def _rotation(yaw, pitch, roll):
    y, p, r = np.radians([yaw, pitch, roll])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return ry @ rx @ rz


def numpy_round_trip(cam: dict, img: np.ndarray) -> np.ndarray:
    w, h, a, b, c, d, e = (cam[k] for k in ("width", "height", "a", "b", "c", "d", "e"))
    d0 = 1 - a - b - c
    big_r = min(w, h) / 2
    f = w / np.radians(cam["hfov"])
    world_from_cam = _rotation(cam["yaw"], cam["pitch"], cam["roll"])
    cx, cy = w / 2 - 0.5 + d, h / 2 - 0.5 + e
    # image -> ray
    xs, ys = img[:, 0] - cx, img[:, 1] - cy
    rho_s = np.hypot(xs, ys) / big_r
    rho = rho_s.copy()
    for _ in range(40):
        fval = rho * (((a * rho + b) * rho + c) * rho + d0) - rho_s
        if np.all(np.abs(fval) <= 16 * np.finfo(float).eps):
            break
        rho -= fval / (((4 * a * rho + 3 * b) * rho + 2 * c) * rho + d0)
    scale = np.where(rho_s > 0, rho / np.where(rho_s > 0, rho_s, 1), 1 / d0)
    x, y = scale * xs, scale * ys
    r = np.hypot(x, y)
    theta = r / f
    s = np.where(r > 0, np.sin(theta) / np.where(r > 0, r, 1), 1 / f)
    ray = np.stack([s * x, s * y, np.cos(theta)], -1) @ world_from_cam.T
    # ray -> image
    u = ray @ world_from_cam
    sxy = np.hypot(u[:, 0], u[:, 1])
    theta = np.arctan2(sxy, u[:, 2])
    k = np.where(sxy > 0, f * theta / np.where(sxy > 0, sxy, 1), f)
    x, y = k * u[:, 0], k * u[:, 1]
    rho = np.hypot(x, y) / big_r
    scale = ((a * rho + b) * rho + c) * rho + d0
    return np.stack([scale * x + cx, scale * y + cy], -1)


# ---------------------------------------------------------------------------------------------
@jax.jit
def rigjax_round_trip(camera: rigjax.Camera, img):
    ray, _ = rigjax.img_to_ray(camera, img)
    back, _ = rigjax.ray_to_img(camera, ray)
    return back


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    img = rng.uniform([-0.5, -0.5], [CAMERA["width"] - 0.5, CAMERA["height"] - 0.5], (args.points, 2))
    rows = []

    baseline = _median_time(lambda: numpy_round_trip(CAMERA, img), args.repeats)
    reference = numpy_round_trip(CAMERA, img)
    rows.append(("numpy, float64 (baseline)", baseline, None, 0.0))

    for dtype in (jnp.float64, jnp.float32):
        camera = rigjax.Camera.create(**CAMERA, dtype=dtype)
        img_dev = jnp.asarray(img, dtype)
        start = time.perf_counter()
        rigjax_round_trip(camera, img_dev).block_until_ready()
        compile_s = time.perf_counter() - start
        warm = _median_time(lambda: rigjax_round_trip(camera, img_dev).block_until_ready(), args.repeats)
        diff = float(np.abs(np.asarray(rigjax_round_trip(camera, img_dev), np.float64) - reference).max())
        rows.append((f"rigjax jit, {jnp.dtype(dtype).name} ({jax.devices()[0].platform})", warm, compile_s, diff))

    print(
        f"image -> ray -> image, {args.points:,} points, full-frame fisheye with a,b,c,d,e; "
        f"median of {args.repeats}; {platform.processor() or platform.machine()}, "
        f"{jax.device_count()} {jax.devices()[0].platform} device(s), jax {jax.__version__}\n"
    )
    print("| implementation | median time | vs numpy | first call (compile + run) | max difference to numpy |")
    print("|---|---|---|---|---|")
    for name, t, compile_s, diff in rows:
        ratio = f"{baseline / t:.1f}x faster" if compile_s is not None else "1.0x"
        first = f"{compile_s:.2f} s" if compile_s is not None else "-"
        print(f"| {name} | {t * 1e3:.1f} ms | {ratio} | {first} | {diff:.1e} px |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
