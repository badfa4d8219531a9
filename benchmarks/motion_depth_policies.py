#!/usr/bin/env python3
"""Benchmark: which points' depths a lens calibration from motion should estimate, by the error each choice leaves

A hand-held dual-fisheye camera turns about its middle, and its lenses, 2.5 cm apart along their axis,
move a few millimetres between frames: a point a metre or two away is seen across frames with a
parallax that no rotation explains. A point held at infinity puts that parallax into the lenses (a
bias); a point given a depth of its own trades the depth against the lens's radial scale (a spread).
This benchmark measures both for each way of choosing the depths, through rigjax's camera model,
linearised at the truth (so no start, pruning or photometry enters):

- the rig: two 1440 px fisheyes of a consumer camera's kind (hfov 193 and 191.5 degrees, Hugin's
  ``a``, ``b``, ``c`` near -0.28, 0.52, -0.14, centres 8-25 px off), lens 1 mounted 0.7 degrees off
  back to back, their centres 1.25 cm before and behind the camera's middle;
- five frames of a hand-held turn: 8 degrees of yaw a frame, up to 3 degrees of pitch and roll;
- two scenes (seeded): ``near``, points in random directions 0.6-50 m away (log-uniform); ``street``,
  the ground 1.5 m below the camera, walls 6-20 m away and sky;
- the matches: every scene point in every pair of images of one lens across frames and in each
  frame's ring (both lenses), exactly placed; Gaussian noise of ``--noise`` px per coordinate for the
  spread;
- the unknowns: each lens's ``v``, ``a``, ``b``, ``c``, ``d``, ``e``, lens 1's mounting, each
  frame's turn (frame 0 holds the rig's orientation), and each point's direction and, where the
  policy frees it, its inverse depth; each image seen from its lens's centre turned with its frame;
- a point is a **pair** (one per matched pair of images, as ``rigjax calibrate --motion`` solves
  today) or a **track** (one per scene point and lens, over every frame that sees it);
- **gated** at ``g``: a point's depth is free where its true inverse depth is at least ``g`` times
  its own standard deviation (its observations' noise, the cameras held), held at infinity
  elsewhere: the decision a gate on the estimated depth makes on average; "free nearer 8 m": the
  truth decides (no estimate can).

Columns: the share of points whose depth is free (ring / across frames); each lens's hfov error
(degrees) and ``e`` error (px), the bias ± its standard deviation; the rays' error (degrees, p95 over
both lenses, as ``benchmarks/lens_from_motion.py`` judges a calibration: ``rigjax.synthetic
.ray_angles_deg``) of the biased calibration, and the median of that p95 over ``--draws`` draws of
the spread about it. The last row of each scene is rigjax's own bundle adjustment
(``rigjax.calibration.motion.solve_motion``) from the truth on the same matches with that noise, as
``--motion`` solves them today: its rays' p95.

    python benchmarks/motion_depth_policies.py [--noise 0.3] [--draws 40] [--scenes near street]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
from _record import recorded

import rigjax
from rigjax import synthetic
from rigjax.calibration.motion import MotionConfig, frames_project, solve_motion
from rigjax.camera.model import Camera, ray_to_img
from rigjax.camera.rotation import world_from_cam, ypr_from_world_from_cam
from rigjax.optimiser.config import OptimiseConfig, Priors

SIZE, FRAMES, OFFSET_M = 1440, 5, 0.0125
LENSES = (
    dict(hfov=193.0, a=-0.28, b=0.52, c=-0.14, d=12.0, e=25.5),
    dict(hfov=191.5, a=-0.25, b=0.47, c=-0.12, d=-8.0, e=19.9),
)
MOUNTING = ((0.0, 0.0, 0.0), (179.3, -0.4, 0.3))
LETTERS = ("hfov", "a", "b", "c", "d", "e")
CENTRES = np.array([[0.0, 0.0, OFFSET_M], [0.0, 0.0, -OFFSET_M]])
# policy: (label, the ring's gate, the points across frames, their gate); a gate is "all", "none",
# a number of standard deviations, or ("nearer", metres)
POLICIES = (
    ("today: ring gated 3, across frames at infinity", 3.0, "pairs", "none"),
    ("ring gated 3, across-frame pairs gated 3", 3.0, "pairs", 3.0),
    ("ring gated 3, across-frame tracks gated 3", 3.0, "tracks", 3.0),
    ("ring gated 3, across-frame tracks gated 2", 3.0, "tracks", 2.0),
    ("ring gated 3, across-frame pairs all free", 3.0, "pairs", "all"),
    ("ring gated 3, across-frame tracks all free", 3.0, "tracks", "all"),
    ("ring gated 3, across-frame tracks free nearer 8 m", 3.0, "tracks", ("nearer", 8.0)),
    ("every depth free (tracks)", "all", "tracks", "all"),
)


def truth_rig() -> rigjax.Project:
    images = [
        rigjax.Image(width=SIZE, height=SIZE, projection=2, **lens, yaw=y, pitch=p, roll=r, filename=f"f0-{k}.png")
        for k, (lens, (y, p, r)) in enumerate(zip(LENSES, MOUNTING))
    ]
    return rigjax.Project.new(rigjax.PanoramaLine(4096, 2048), images)


def turns_of(seed: int = 1) -> np.ndarray:
    """Each frame's turn, frame 0's the identity: 8 degrees of yaw a frame, a hand's wobble."""
    rng = np.random.default_rng(seed)
    turns = np.stack(
        [np.asarray(world_from_cam(8.0 * f, rng.uniform(-3, 3), rng.uniform(-3, 3))) for f in range(FRAMES)]
    )
    return turns[0].T[None] @ turns


def scene_of(kind: str) -> np.ndarray:
    if kind == "near":
        return synthetic.scene_points(600, near=0.6, far=50.0, seed=4)
    rng = np.random.default_rng(4)
    d = rng.normal(size=(900, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    wall = rng.uniform(6.0, 20.0, len(d))
    distance = np.where(d[:, 1] > 0.05, 1.5 / np.maximum(d[:, 1], 1e-3), np.where(rng.random(len(d)) < 0.5, wall, 1e4))
    return d * np.minimum(distance, 1e4)[:, None]  # +y is down: the ground below


class Problem:
    """The linearised calibration of one scene's matches (module docstring)."""

    def __init__(self, scene: np.ndarray, noise_px: float):
        self.truth, self.turns, self.scene, self.noise = truth_rig(), turns_of(), scene, noise_px
        names = [[f"f{f}-{k}.png" for k in range(2)] for f in range(FRAMES)]
        self.frames = frames_project(self.truth, self.turns, names)
        self.world = np.einsum("fij,lj->fli", self.turns, CENTRES).reshape(-1, 3)
        matched, index = synthetic.control_points_from_scene(self.frames, self.world, scene)
        cps = matched.control_points
        a, b = np.asarray(cps.image_a), np.asarray(cps.image_b)
        keep = (a // 2 == b // 2) | (a % 2 == b % 2)  # the ring, and each lens with itself across frames
        self.cps = rigjax.ControlPoints(
            *(np.asarray(getattr(cps, x))[keep] for x in ("image_a", "image_b", "xy_a", "xy_b", "kind"))
        )
        self.a, self.b, self.index = a[keep], b[keep], index[keep]
        self.ring = self.a // 2 == self.b // 2
        self.mount0 = np.asarray(world_from_cam(*MOUNTING[0]))
        self.theta = np.concatenate(
            [
                np.array([[lens[x] for x in LETTERS] for lens in LENSES]).ravel(),
                MOUNTING[1],
                np.asarray(ypr_from_world_from_cam(self.turns[1:])).ravel(),
            ]
        )
        self.jacobians = jax.jit(jax.vmap(jax.jacfwd(self.rows, argnums=(0, 1)), in_axes=(None, 0, 0, 0, 0, 0)))
        self.residuals = jax.jit(jax.vmap(self.rows, in_axes=(None, 0, 0, 0, 0, 0)))

    def groups(self, across: str) -> list[tuple[np.ndarray, int]]:
        """The ring's pairs, then the points across frames: ``(images, scene point)`` each."""
        pairs = [(np.array([x, y]), i) for x, y, i in zip(self.a, self.b, self.index)]
        ring = [g for g, r in zip(pairs, self.ring) if r]
        if across == "pairs":
            return ring + [g for g, r in zip(pairs, self.ring) if not r]
        tracks = []
        for i in np.unique(self.index[~self.ring]):
            for lens in (0, 1):
                m = (self.index == i) & ~self.ring & (self.a % 2 == lens)
                if m.any():
                    tracks.append((np.unique(np.concatenate([self.a[m], self.b[m]])), int(i)))
        return ring + tracks

    def camera(self, theta, image):
        frame, lens = image // 2, image % 2
        letters = theta[:12].reshape(2, 6)[lens]
        mount = jnp.where(lens == 0, self.mount0, world_from_cam(theta[12], theta[13], theta[14]))
        turn = theta[15:].reshape(FRAMES - 1, 3)[jnp.maximum(frame - 1, 0)]
        turn = jnp.where(frame == 0, jnp.eye(3), world_from_cam(*turn))
        ypr = ypr_from_world_from_cam(turn @ mount)
        return Camera(jnp.asarray(2), float(SIZE), float(SIZE), *letters, *ypr), turn @ jnp.asarray(CENTRES)[lens]

    def rows(self, theta, point, tangents, images, used, held):
        """A point's residuals (px) in its images: the point at ``point`` (tangent-plane offsets of
        its direction, inverse depth; ``held``: at infinity)."""
        d = tangents[0] + point[0] * tangents[1] + point[1] * tangents[2]
        d = d / jnp.linalg.norm(d)
        q = point[2] * (1.0 - held)

        def one(image):
            camera, centre = self.camera(theta, image)
            return ray_to_img(camera, d - q * centre)[0]

        return (jax.vmap(one)(images) * used[:, None]).ravel()

    def analyse(self, groups, gates):
        """``(bias, covariance, free)`` of the camera unknowns, each group's depth free as ``gates``
        (one gate per group) decides."""
        width = max(len(g[0]) for g in groups)
        images = np.array([np.pad(g[0], (0, width - len(g[0])), mode="edge") for g in groups])
        used = np.array([np.pad(np.ones(len(g[0])), (0, width - len(g[0]))) for g in groups])
        x = self.scene[[g[1] for g in groups]]
        q = 1.0 / np.linalg.norm(x, axis=1)
        tangents = np.stack([_tangents(p / np.linalg.norm(p)) for p in x])
        point = np.stack([np.zeros_like(q), np.zeros_like(q), q], 1)
        data = (jnp.asarray(point), jnp.asarray(tangents), jnp.asarray(images), jnp.asarray(used))
        theta = jnp.asarray(self.theta)
        d_cam, d_point = (np.array(j) for j in self.jacobians(theta, *data, jnp.zeros(len(q))))
        own_sd = self.noise * np.sqrt(np.linalg.inv(np.einsum("nri,nrj->nij", d_point, d_point))[:, 2, 2])
        free = np.array([_free(gate, qi, sd) for gate, qi, sd in zip(gates, q, own_sd)])
        held = (~free).astype(float)
        # the residuals at the truth with the held points at infinity: their unmodelled parallax
        r = np.asarray(self.residuals(theta, *data, jnp.asarray(held))) - np.asarray(
            self.residuals(theta, *data, jnp.zeros(len(q)))
        )
        d_point[..., 2] *= free[:, None]
        v = np.einsum("nri,nrj->nij", d_point, d_point)
        v += np.eye(3)[None] * (np.diagonal(v, axis1=1, axis2=2) <= 0.0)[:, :, None]
        w = np.einsum("nri,nrj->nij", d_cam, d_point)
        v_inv = np.linalg.inv(v)
        reduced = np.einsum("nri,nrj->ij", d_cam, d_cam) - np.einsum("nij,njk,nlk->il", w, v_inv, w)
        gradient = np.einsum("nri,nr->i", d_cam, r) - np.einsum("nij,njk,nrk,nr->i", w, v_inv, d_point, r)
        inverse = np.linalg.inv(reduced)
        return -inverse @ gradient, self.noise**2 * inverse, free

    def rig_at(self, theta) -> rigjax.Project:
        images = [
            image.replace(**{x: float(theta[6 * k + i]) for i, x in enumerate(LETTERS)})
            for k, image in enumerate(self.truth.images)
        ]
        images[1] = images[1].replace(yaw=float(theta[12]), pitch=float(theta[13]), roll=float(theta[14]))
        return self.truth.replace(images=images)

    def p95(self, rig: rigjax.Project) -> float:
        return max(float(np.percentile(e, 95)) for e in synthetic.ray_angles_deg(rig, self.truth))

    def solved_today(self) -> float:
        """Rigjax's bundle adjustment from the truth on these matches with noise, as ``--motion``
        solves them: its rays' p95."""
        noise = np.random.default_rng(7).normal(scale=self.noise, size=(2, len(self.a), 2))
        noisy = dataclasses.replace(self.cps, xy_a=self.cps.xy_a + noise[0], xy_b=self.cps.xy_b + noise[1])
        start = self.frames.replace(control_points=noisy)
        fit = solve_motion(start, 2, MotionConfig(priors=Priors()), OptimiseConfig(prune=None), centres=CENTRES)
        return self.p95(fit.rig)


def _tangents(d: np.ndarray) -> np.ndarray:
    t = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    return np.stack([d, t, np.cross(d, t)])


def _free(gate, q: float, sd: float) -> bool:
    if gate == "all":
        return True
    if gate == "none":
        return False
    if isinstance(gate, tuple):
        return 1.0 / q < gate[1]
    return q / sd >= gate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise", type=float, default=0.3, help="px per coordinate, for the spread")
    parser.add_argument("--draws", type=int, default=40)
    parser.add_argument("--scenes", nargs="+", default=["near", "street"], choices=["near", "street"])
    args = parser.parse_args()
    print(
        f"Five frames, {args.noise} px of noise per coordinate; biases ± standard deviations; "
        f"rays: p95 (degrees) over both lenses, the bias alone and the median over {args.draws} draws."
    )
    for kind in args.scenes:
        problem = Problem(scene_of(kind), args.noise)
        seen = np.unique(problem.index)
        distance = np.linalg.norm(problem.scene[seen], axis=1)
        print(
            f"\n**{kind}**: {len(seen)} scene points (median {np.median(distance):.1f} m away, "
            f"{np.mean(distance < 3.0):.0%} nearer than 3 m), {len(problem.a)} matched pairs "
            f"({int(problem.ring.sum())} in the rings)\n"
        )
        print(
            "| depths | free: ring / across | hfov 0 | hfov 1 | e 0 (px) | e 1 (px) | rays: bias | rays: with noise |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for label, ring_gate, across, gate in POLICIES:
            groups = problem.groups(across)
            n_ring = int(problem.ring.sum())
            gates = [ring_gate] * n_ring + [gate] * (len(groups) - n_ring)
            bias, covariance, free = problem.analyse(groups, gates)
            sd = np.sqrt(np.diag(covariance))
            draws = np.random.default_rng(0).multivariate_normal(problem.theta + bias, covariance, args.draws)
            noisy = np.median([problem.p95(problem.rig_at(t)) for t in draws])
            cells = [f"{bias[i]:+.3f} ± {sd[i]:.3f}" for i in (0, 6)] + [
                f"{bias[i]:+.2f} ± {sd[i]:.2f}" for i in (5, 11)
            ]
            print(
                f"| {label} | {free[:n_ring].mean():.0%} / {free[n_ring:].mean():.0%} | {' | '.join(cells)} | "
                f"{problem.p95(problem.rig_at(problem.theta + bias)):.3f} | {noisy:.3f} |",
                flush=True,
            )
        print(f"| rigjax's bundle adjustment today, solved | | | | | | | {problem.solved_today():.3f} |", flush=True)
        print(f"{kind} done", file=sys.stderr)


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
