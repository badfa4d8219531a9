"""Straight-line control points (t3+): libpano13's residual against an independent formula on
Hugin-verified panorama coordinates, and lines that level a rig no match can level."""

from __future__ import annotations

import numpy as np
import pytest

import rigjax
from rigjax import synthetic
from rigjax.optimiser.problem import _straight_line_rows
from rigjax.optimiser.residuals import LineGroups, straight_line_residuals


def _rig_with_lines(noise_px: float, seed: int) -> rigjax.Project:
    truth = synthetic.cube_rig(orientation_jitter_deg=3.0, seed=seed)
    truth = synthetic.control_points_from_truth(truth, 600, noise_px=noise_px, seed=seed + 1)
    return synthetic.vertical_lines_from_truth(truth, n_lines=5, points_per_line=6, noise_px=noise_px, seed=seed + 2)


def _reference(project: rigjax.Project) -> np.ndarray:
    """Distances of the two other panorama points from the line through the farthest pair, as a
    2-D cross product, from ``img_to_pano`` (the transform checked against Hugin's pano_trafo)."""
    cps, cameras, canvas = project.control_points, project.cameras(), project.canvas()

    def pano(image, xy):
        out, _ = rigjax.img_to_pano(cameras.take(int(image)), canvas, np.asarray(xy))
        return np.asarray(out)

    out = []
    for k, j in _straight_line_rows(project, np.ones(len(cps))):
        p = [
            pano(cps.image_a[k], cps.xy_a[k]),
            pano(cps.image_b[k], cps.xy_b[k]),
            pano(cps.image_a[j], cps.xy_a[j]),
            pano(cps.image_b[j], cps.xy_b[j]),
        ]
        pairs = [(i, m) for i in range(4) for m in range(i + 1, 4)]
        i, m = max(pairs, key=lambda pair: np.sum((p[pair[0]] - p[pair[1]]) ** 2))
        u = (p[m] - p[i]) / np.linalg.norm(p[m] - p[i])
        rest = [q for q in range(4) if q not in (i, m)]
        # signed distance = cross(u, q - p_i); libpano13's sign convention is the opposite
        out.append([-(u[0] * (p[q][1] - p[i][1]) - u[1] * (p[q][0] - p[i][0])) for q in rest])
    return np.array(out)


def _ours(project: rigjax.Project) -> np.ndarray:
    cps = project.control_points
    rows = _straight_line_rows(project, np.ones(len(cps)))
    image = np.array([[cps.image_a[k], cps.image_b[k], cps.image_a[j], cps.image_b[j]] for k, j in rows])
    xy = np.array([[cps.xy_a[k], cps.xy_b[k], cps.xy_a[j], cps.xy_b[j]] for k, j in rows])
    return np.asarray(straight_line_residuals(project.cameras(), LineGroups(image, xy), project.canvas()))


def test_straight_line_residual_matches_an_independent_formula():
    truth = _rig_with_lines(noise_px=0.0, seed=21)
    np.testing.assert_allclose(_ours(truth), 0.0, atol=1e-6)  # the lines are straight at the truth
    start = synthetic.perturb(truth, angle_deg=(1, 3), hfov_offset_deg=(1, 2), seed=22)
    ours, reference = _ours(start), _reference(start)
    assert np.abs(reference).max() > 5.0  # off the truth the lines bend, by pixels
    np.testing.assert_allclose(ours, reference, atol=1e-7)


def test_a_line_of_one_point_has_no_residual():
    truth = _rig_with_lines(noise_px=0.0, seed=23)
    cps = truth.control_points
    kind = cps.kind.copy()
    kind[np.flatnonzero(kind == 3)[0]] = 99  # t99: alone on its line
    lone = truth.replace(control_points=rigjax.ControlPoints(cps.image_a, cps.image_b, cps.xy_a, cps.xy_b, kind))
    rows = _straight_line_rows(lone, np.ones(len(cps)))
    assert all(kind[k] != 99 for k, _ in rows)  # no row of its own; the rest of t3 still pair up
    assert len(rows) == len(_straight_line_rows(truth, np.ones(len(cps)))) - 1


def _tilted_start(truth: rigjax.Project, seed: int) -> rigjax.Project:
    """Cameras 1-3 degrees off, and the anchor's pitch and roll 3 degrees off and free (p0 r0)."""
    start = synthetic.perturb(truth, angle_deg=(1, 3), hfov_offset_deg=(0, 0), b=None, seed=seed)
    tilted = list(start.images)
    tilted[0] = tilted[0].replace(pitch=tilted[0].pitch + 3.0, roll=tilted[0].roll - 3.0)
    variables = [rigjax.OptVariable("p", 0), rigjax.OptVariable("r", 0)]
    variables += [rigjax.OptVariable(letter, k) for k in range(1, 6) for letter in "ypr"]
    return start.replace(images=tuple(tilted), variables=tuple(variables))


def _tilt_error_deg(project: rigjax.Project, truth: rigjax.Project) -> float:
    """Angle between the anchor camera's down axis in the world and the truth's."""
    down, down_truth = (np.asarray(p.cameras().world_from_cam)[0][:, 1] for p in (project, truth))
    return float(np.degrees(np.arccos(np.clip(down @ down_truth, -1.0, 1.0))))


@pytest.mark.parametrize("objective", ["transfer", "hugin"])
def test_straight_lines_level_the_rig(objective):
    """Matches fix the cameras relative to each other; only the lines fix the rig's tilt. Without
    noise the tilt comes back exactly; with noise, the optimum is the one reached from the truth."""
    exact = _tilted_start(_rig_with_lines(noise_px=0.0, seed=24), seed=25)
    truth = _rig_with_lines(noise_px=0.0, seed=24)
    assert _tilt_error_deg(exact, truth) > 2.0
    config = rigjax.OptimiseConfig(pto_vars=True, objective=objective)
    result = rigjax.optimise(exact, config)
    assert result.ok and _tilt_error_deg(result.project, truth) < 1e-6

    noisy_truth = _rig_with_lines(noise_px=0.3, seed=24)
    noisy = rigjax.optimise(_tilted_start(noisy_truth, seed=25), config)
    best = rigjax.optimise(noisy_truth.replace(variables=exact.variables), config)
    assert noisy.ok and _tilt_error_deg(noisy.project, best.project) < 1e-5
    assert _tilt_error_deg(best.project, truth) < 0.2  # what 0.3 px on 30 line points allows

    # Without the line points (weight 0: the same compiled solve) nothing sees the tilt: LM drifts
    # along the free rotation (the residuals reach zero at any tilt) and the rig stays tilted.
    bare = rigjax.optimise(exact, config, weights=(exact.control_points.kind == 0) * 1.0)
    assert _tilt_error_deg(bare.project, truth) > 0.5
