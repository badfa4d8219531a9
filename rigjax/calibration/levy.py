"""Lévy-flight neighbourhood search: starts for Levenberg-Marquardt far from a poor initial guess.

Candidates are the start's yaw/pitch/roll moved by Lévy-distributed steps (Mantegna's
algorithm): most steps are small, a few are long jumps, so one batch both refines the start and
probes distant basins. All candidates are scored in one compiled, vmapped call by a truncated
cost (the mean of ``min(e^2, scale^2)`` over the control points' transfer errors ``e``: wrong
matches and points thrown out of view cannot dominate it). The search runs a few generations,
each around the best candidate so far; the best ``starts`` distinct candidates of the last
generation, the start itself among them, become LM starts for :func:`rigjax.optimise_batch`.

Mantegna (1994): ``step = u / |v|^(1/beta)``, ``u ~ N(0, sigma_u^2)``, ``v ~ N(0, 1)``,
``sigma_u = [Gamma(1+beta) sin(pi beta/2) / (Gamma((1+beta)/2) beta 2^((beta-1)/2))]^(1/beta)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..camera.model import Camera
from ..camera.panorama import Equirect
from ..errors import RigjaxError
from ..optimiser.problem import padded_points
from ..optimiser.residuals import NORMAL, PointArrays, point_residuals
from ..pto.project import Project


@dataclass(frozen=True)
class LevyConfig:
    """Settings of :func:`levy_starts`: ``candidates`` per generation, ``generations``, the step
    ``scale_deg`` (degrees per unit Lévy step), the index ``beta`` in (0, 2], the number of LM
    ``starts`` returned, and the truncation ``cost_scale_px`` of the score."""

    candidates: int = 256
    generations: int = 3
    scale_deg: float = 10.0
    beta: float = 1.5
    starts: int = 8
    cost_scale_px: float = 20.0

    def __post_init__(self) -> None:
        if self.candidates < 1 or self.generations < 1 or self.starts < 1:
            raise RigjaxError("levy candidates, generations and starts must be >= 1")
        if not 0.0 < self.beta <= 2.0:
            raise RigjaxError(f"levy beta must be in (0, 2], got {self.beta!r}")
        if not (self.scale_deg > 0 and self.cost_scale_px > 0):
            raise RigjaxError("levy scale_deg and cost_scale_px must be > 0")


def mantegna_sigma_u(beta: float) -> float:
    """Mantegna's scale of the numerator, ``sigma_u`` (see the module docstring)."""
    return (
        math.gamma(1 + beta)
        * math.sin(math.pi * beta / 2)
        / (math.gamma((1 + beta) / 2) * beta * 2 ** ((beta - 1) / 2))
    ) ** (1 / beta)


def mantegna_steps(rng: np.random.Generator, shape: tuple[int, ...], beta: float) -> np.ndarray:
    """Lévy-distributed steps of index ``beta`` by Mantegna's algorithm (unit scale)."""
    u = rng.normal(0.0, mantegna_sigma_u(beta), shape)
    v = rng.normal(0.0, 1.0, shape)
    return u / np.abs(v) ** (1 / beta)


@partial(jax.jit, static_argnames=("projection",))
def _scores(cameras: Camera, ypr, points: PointArrays, canvas: Equirect, weight, scale, projection):
    """Truncated cost of each candidate orientation set ``ypr`` (candidates, n_images, 3)."""

    def one(angles):
        candidate = cameras._replace(yaw=angles[:, 0], pitch=angles[:, 1], roll=angles[:, 2])
        transfer = point_residuals(candidate, points, canvas, projection).transfer
        e2 = jnp.stack([transfer[:, 0] ** 2 + transfer[:, 1] ** 2, transfer[:, 2] ** 2 + transfer[:, 3] ** 2], -1)
        return jnp.sum(weight[:, None] * jnp.minimum(e2, scale**2)) / jnp.maximum(2 * jnp.sum(weight), 1.0)

    return jax.vmap(one)(ypr)


def _scorer(project: Project, scale_px: float, weights: np.ndarray | None):
    """The truncated cost of a project's orientation sets, with the points padded and sent to the
    device once; compiled once per (candidates, padded points) shape."""
    n = len(project.control_points)
    weight = np.ones(n) if weights is None else np.asarray(weights, float)
    weight = weight * (project.control_points.kind == NORMAL)
    points, padded = padded_points(project, weight)
    projections = {image.projection for image in project.images}
    projection = projections.pop() if len(projections) == 1 else None
    data = (
        project.cameras(),
        jax.tree_util.tree_map(jnp.asarray, points),
        project.canvas(),
        jnp.asarray(padded),
        jnp.asarray(float(scale_px)),
    )

    def scores(ypr: np.ndarray) -> np.ndarray:
        cameras, points_, canvas, weight_, scale = data
        return np.asarray(_scores(cameras, jnp.asarray(ypr), points_, canvas, weight_, scale, projection))

    return scores


def score(project: Project, ypr: np.ndarray, scale_px: float, weights: np.ndarray | None = None) -> np.ndarray:
    """The truncated cost (px^2) of each row of ``ypr`` (candidates, n_images, 3) as the
    project's orientations; other parameters as in the project."""
    return _scorer(project, scale_px, weights)(ypr)


def levy_starts(
    project: Project,
    config: LevyConfig | None = None,
    *,
    anchor: int = 0,
    seed: int = 0,
    weights: np.ndarray | None = None,
) -> tuple[list[Project], np.ndarray]:
    """The best ``config.starts`` projects found by the search, best first, and their scores.

    The anchor's orientation is never moved. Returns at most ``starts`` projects, the given
    start always among them (so the search can only add starts, never lose the plain one).
    """
    config = config or LevyConfig()
    rng = np.random.default_rng(seed)
    n_images = len(project.images)
    start = np.array([[im.yaw, im.pitch, im.roll] for im in project.images])
    movable = np.ones((n_images, 1))
    movable[anchor] = 0.0
    scorer = _scorer(project, config.cost_scale_px, weights)
    centre, pool, pool_scores = start, [start[None]], []
    for generation in range(config.generations):
        steps = mantegna_steps(rng, (config.candidates, n_images, 3), config.beta) * config.scale_deg
        # Long jumps are folded back into a turn (a step of 500 degrees is a step of 140).
        steps = (steps + 180.0) % 360.0 - 180.0
        candidates = np.concatenate([centre[None], centre[None] + steps * movable[None]])
        scores = scorer(candidates)
        if generation == 0:
            pool_scores.append(scores[:1])  # row 0 of the first generation is the start itself
        centre = candidates[int(np.argmin(scores))]
        best = np.argsort(scores)[: config.starts]
        pool.append(candidates[best])
        pool_scores.append(scores[best])
    pool, scores = np.concatenate(pool), np.concatenate(pool_scores)
    _, first = np.unique(np.round(pool, 9).reshape(len(pool), -1), axis=0, return_index=True)
    keep = np.sort(first)  # distinct candidates; the start stays at index 0
    pool, scores = pool[keep], scores[keep]
    order = [0] + [int(k) for k in np.argsort(scores) if k != 0]  # the plain start first, then the best
    chosen = sorted(order[: config.starts], key=lambda k: scores[k])
    projects = []
    for k in chosen:
        images = tuple(
            im.replace(yaw=float(y), pitch=float(p), roll=float(r)) for im, (y, p, r) in zip(project.images, pool[k])
        )
        projects.append(project.replace(images=images))
    return projects, scores[chosen]
