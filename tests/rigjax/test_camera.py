"""The camera model: conventions from closed forms, round trips, gradients against finite
differences (float64), jit/vmap consistency and the compilation cache."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigjax
from rigjax import Camera, Equirect
from rigjax.camera.distortion import distort_radius, max_radius, undistort_radius

LENSES = [int(p) for p in rigjax.Projection]


def _camera(projection, **kw):
    base = dict(
        projection=projection,
        width=1600,
        height=1200,
        hfov=70.0 if projection == 0 else 150.0,
        a=0.004,
        b=-0.03,
        c=0.01,
        d=11.0,
        e=-6.5,
        yaw=-35.0,
        pitch=25.0,
        roll=160.0,
    )
    if projection == 4:
        base.update(width=1600, height=800, hfov=200.0)
    base.update(kw)
    return Camera.create(**base)


def test_pixel_centre_convention():
    # Hugin's convention: (W/2 - 0.5 + d, H/2 - 0.5 + e) is the optical axis, which an
    # unrotated camera sends to the canvas centre (W_p/2 - 0.5, H_p/2 - 0.5).
    cam = _camera(3, yaw=0.0, pitch=0.0, roll=0.0)
    pano, ok = rigjax.img_to_pano(cam, Equirect.create(3600, 1800), jnp.array([799.5 + 11.0, 599.5 - 6.5]))
    assert ok
    np.testing.assert_allclose(pano, [1799.5, 899.5], atol=1e-9)


@pytest.mark.parametrize("yaw, pitch", [(30.0, 0.0), (-120.0, 0.0), (0.0, 40.0), (0.0, -75.0)])
def test_yaw_moves_right_and_pitch_moves_up(yaw, pitch):
    cam = _camera(3, yaw=yaw, pitch=pitch, roll=0.0, d=0.0, e=0.0)
    canvas = Equirect.create(3600, 1800)  # 10 px per degree
    pano, _ = rigjax.img_to_pano(cam, canvas, jnp.array([799.5, 599.5]))
    np.testing.assert_allclose(pano, [1799.5 + 10 * yaw, 899.5 - 10 * pitch], atol=1e-9)


def test_roll_turns_the_image_clockwise():
    # +roll: the image's right edge points down (reference §3).
    cam = _camera(0, yaw=0.0, pitch=0.0, roll=30.0, a=0.0, b=0.0, c=0.0, d=0.0, e=0.0)
    ray, _ = rigjax.img_to_ray(cam, jnp.array([1599.5, 599.5]))
    assert ray[1] > 0.0
    np.testing.assert_allclose(np.degrees(np.arctan2(ray[1], ray[0])), 30.0, atol=1e-9)


@pytest.mark.parametrize(
    "projection, theta_of_r",
    [
        (0, lambda r, f: np.arctan(r / f)),
        (3, lambda r, f: r / f),
        (8, lambda r, f: np.arcsin(r / f)),
        (10, lambda r, f: 2 * np.arctan(r / (2 * f))),
        (21, lambda r, f: 2 * np.arcsin(r / (2 * f))),
    ],
)
def test_projection_radius_laws(projection, theta_of_r):
    # Without distortion the angle from the axis follows the lens law with Hugin's focal length
    # at the image's horizontal edge: theta(W/2) = hfov/2 for every lens (definition of hfov).
    cam = _camera(projection, a=0.0, b=0.0, c=0.0, d=0.0, e=0.0, yaw=0.0, pitch=0.0, roll=0.0)
    edge, _ = rigjax.img_to_ray(cam, jnp.array([799.5 + 800.0, 599.5]))
    np.testing.assert_allclose(np.degrees(np.arccos(edge[2])), float(cam.hfov) / 2, atol=1e-9)
    r = np.linspace(1.0, 500.0, 7)
    rays, _ = rigjax.img_to_ray(cam, jnp.stack([799.5 + r, 599.5 + 0 * r], -1))
    np.testing.assert_allclose(np.arccos(np.asarray(rays)[:, 2]), theta_of_r(r, float(cam.focal)), atol=1e-12)


def test_radial_polynomial_and_its_range():
    a, b, c = 0.02, -0.15, 0.03
    rho = np.linspace(0.0, 1.5, 31)
    np.testing.assert_allclose(distort_radius(a, b, c, rho), rho * (a * rho**3 + b * rho**2 + c * rho + 1 - a - b - c))
    # End of the invertible range against numpy's polynomial roots.
    for coeffs in [
        (0.02, -0.15, 0.03),
        (0.0, -0.4, 0.0),
        (0.0, 0.0, -0.6),
        (0.1, 0.2, 0.0),
        (0.0, 0.0, 0.0),
        (-0.05, 0.1, -0.2),
        (0.3, -0.9, 0.2),
    ]:
        a, b, c = coeffs
        roots = np.roots([4 * a, 3 * b, 2 * c, 1 - a - b - c]) if any(coeffs) else np.array([])
        positive = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
        expected = min(positive) if positive else np.inf
        np.testing.assert_allclose(max_radius(a, b, c), expected, rtol=1e-10)


def test_undistort_inverts_distort_and_flags_the_rest():
    a, b, c = 0.0, -0.15, 0.0  # max of P at rho_c = 1.599, P(rho_c) = 1.226
    rho = np.linspace(0.0, 1.59, 50)
    back, ok = undistort_radius(a, b, c, distort_radius(a, b, c, rho))
    assert np.all(ok)
    np.testing.assert_allclose(back, rho, atol=1e-12)
    _, ok = undistort_radius(a, b, c, np.array([1.2, 1.25, 1.5]))
    assert ok.tolist() == [True, False, False]


def test_undistort_derivatives_match_finite_differences():
    # Implicit differentiation, checked where Hugin's own loop would have a dead zone (a=b=c=0).
    for params in [(0.0, 0.0, 0.0, 0.7), (0.01, -0.05, 0.02, 1.1)]:
        grad = jax.grad(lambda p: undistort_radius(*p)[0])(jnp.array(params))
        h = 1e-6
        fd = [
            (undistort_radius(*(np.array(params) + h * e))[0] - undistort_radius(*(np.array(params) - h * e))[0])
            / (2 * h)
            for e in np.eye(4)
        ]
        np.testing.assert_allclose(grad, fd, rtol=1e-7, atol=1e-9)
        assert abs(grad[1]) > 1e-3  # d rho / d b is not zero at b = 0


FIELDS = ["hfov", "a", "b", "c", "d", "e", "yaw", "pitch", "roll"]


def _fd_jacobian(fn, cam, field, h):
    step = h.reshape(-1)
    plus = cam._replace(**{field: getattr(cam, field) + step})
    minus = cam._replace(**{field: getattr(cam, field) - step})
    return (np.asarray(fn(plus)) - np.asarray(fn(minus))) / (2 * h)


def test_gradients_match_finite_differences():
    # All lens types at once: cameras are independent, so one batched Jacobian holds every lens's
    # derivatives on its diagonal, and each finite difference perturbs all cameras together.
    cams = [_camera(p) for p in LENSES]
    cam = jax.tree_util.tree_map(lambda *f: jnp.stack(f), *cams)
    canvas = Equirect.create(3000, 1500)
    rng = np.random.default_rng(0)
    img = np.stack([rng.uniform([300, 200], [1300, 600] if p == 4 else [1300, 950], (16, 2)) for p in LENSES])
    img[[k for k, p in enumerate(LENSES) if p != 4], 0] = [799.5 + 11.0, 599.5 - 6.5]  # the distortion centre
    forward = jax.jit(lambda c: rigjax.img_to_pano(c.take(np.arange(len(LENSES))[:, None]), canvas, img)[0])
    _, ok = rigjax.img_to_pano(cam.take(np.arange(len(LENSES))[:, None]), canvas, img)
    assert np.all(ok)
    pano = np.asarray(forward(cam))
    reverse = jax.jit(lambda c: rigjax.pano_to_img(c.take(np.arange(len(LENSES))[:, None]), canvas, pano)[0])
    diagonal = np.arange(len(LENSES))
    params = {field: getattr(cam, field) for field in FIELDS}  # differentiable fields (not the lens type)
    for fn in (forward, reverse):
        jac = jax.jacfwd(lambda p: fn(cam._replace(**p)))(params)
        jac_rev = jax.jacrev(lambda p: fn(cam._replace(**p)))(params)
        for field in FIELDS:
            h = 1e-6 * np.maximum(1.0, np.abs(np.asarray(getattr(cam, field))))
            fd = _fd_jacobian(fn, cam, field, h[:, None, None])
            got = np.asarray(jac[field])[diagonal, :, :, diagonal]  # (lens, point, xy)
            assert np.all(np.isfinite(got)), field
            for k, lens in enumerate(LENSES):
                np.testing.assert_allclose(
                    got[k],
                    fd[k],
                    rtol=2e-5,
                    atol=2e-5 * max(1.0, np.abs(fd[k]).max()),
                    err_msg=f"{field}, lens f{lens}",
                )
            np.testing.assert_allclose(
                np.asarray(jac_rev[field]), np.asarray(jac[field]), rtol=1e-10, atol=1e-9, err_msg=field
            )
    # With respect to the pixel coordinates (d pano / d img), against finite differences.
    to_pano = jax.jit(lambda xy: rigjax.img_to_pano(cams[1], canvas, xy)[0])
    point_jac = jax.jacfwd(to_pano)(jnp.asarray(img[1, 3]))
    fd = np.stack([(to_pano(img[1, 3] + h) - to_pano(img[1, 3] - h)) / 2e-4 for h in np.eye(2) * 1e-4], -1)
    np.testing.assert_allclose(point_jac, fd, rtol=1e-6)


@pytest.mark.parametrize("projection", LENSES)
def test_image_ray_image_round_trip(projection):
    cam = _camera(projection)
    h, w = int(cam.height), int(cam.width)
    gx, gy = np.meshgrid(np.linspace(-0.5, w - 0.5, 41), np.linspace(-0.5, h - 0.5, 31))
    img = np.stack([gx.ravel(), gy.ravel()], -1)
    ray, ok = rigjax.img_to_ray(cam, img)
    np.testing.assert_allclose(np.linalg.norm(ray, axis=-1), 1.0, atol=1e-12)
    back, ok_back = rigjax.ray_to_img(cam, ray)
    both = np.asarray(ok & ok_back)
    assert both.mean() > 0.8
    np.testing.assert_allclose(np.asarray(back)[both], img[both], atol=1e-8)


def test_batched_vmapped_and_looped_agree_and_jit_equals_eager():
    cams = rigjax.synthetic.cube_rig(orientation_jitter_deg=4, seed=7).cameras()
    canvas = Equirect.create(3600, 1800)
    pts = np.random.default_rng(0).uniform([0, 0], [1440, 1080], (6, 20, 2))
    jitted_fn = jax.jit(rigjax.img_to_pano)
    vmapped, _ = jax.jit(jax.vmap(rigjax.img_to_pano, in_axes=(0, None, 0)))(cams, canvas, pts)
    eager, _ = rigjax.img_to_pano(cams.take(np.arange(6)[:, None]), canvas, pts)
    looped = np.stack([np.asarray(jitted_fn(cams.take(k), canvas, pts[k])[0]) for k in range(6)])
    jitted, _ = jitted_fn(cams.take(np.arange(6)[:, None]), canvas, pts)
    # Per-point lens types (the select path) keep the types: float points, boolean masks.
    out, valid = rigjax.transform_points(cams, canvas, np.repeat(np.arange(6), 20), pts.reshape(-1, 2), reverse=False)
    assert out.dtype == np.float64 and valid.dtype == np.bool_
    np.testing.assert_allclose(out.reshape(6, 20, 2), looped, atol=1e-10)
    np.testing.assert_allclose(vmapped, looped, atol=1e-10)
    np.testing.assert_allclose(eager, looped, atol=1e-10)
    np.testing.assert_allclose(jitted, looped, atol=1e-10)


def test_new_data_of_the_same_shape_does_not_recompile():
    from rigjax.camera.trafo import transform_batch

    p1 = rigjax.synthetic.cube_rig(seed=1).cameras()
    p2 = rigjax.synthetic.cube_rig(orientation_jitter_deg=5, hfov=118.0, seed=2).cameras()
    canvas = Equirect.create(3600, 1800)
    rng = np.random.default_rng(0)
    rigjax.transform_points(p1, canvas, rng.integers(0, 6, 100), rng.uniform(0, 1000, (100, 2)), reverse=False)
    before = transform_batch._cache_size()
    for cams, reverse in [(p2, False), (p1, True), (p2, True)]:
        rigjax.transform_points(cams, canvas, rng.integers(0, 6, 150), rng.uniform(0, 1000, (150, 2)), reverse=reverse)
    assert transform_batch._cache_size() == before


def test_float32_stays_float32_and_close_to_float64():
    cam64 = _camera(3)
    cam32 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32) if x.dtype == jnp.float64 else x, cam64)
    img = np.array([[100.0, 200.0], [1500.0, 1100.0], [810.5, 593.0]])
    out32, ok32 = rigjax.img_to_pano(cam32, Equirect.create(3000, 1500, dtype=jnp.float32), img.astype(np.float32))
    out64, _ = rigjax.img_to_pano(cam64, Equirect.create(3000, 1500), img)
    assert out32.dtype == jnp.float32 and bool(ok32.all())
    np.testing.assert_allclose(out32, out64, atol=2e-3)
