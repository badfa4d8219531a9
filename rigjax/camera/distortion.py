"""PanoTools radial distortion: the polynomial, its invertible range, and its inverse.

Convention:
    Radii are *normalised* by ``R = min(width, height) / 2`` of the full image and measured from
    the distortion centre (image centre plus the shifts ``d, e``). ``rho`` is the ideal
    (undistorted) radius, ``rho_src`` the radius in the source image:

        rho_src = P(rho) = rho * (a rho^3 + b rho^2 + c rho + d0),    d0 = 1 - a - b - c

    so ``P(1) = 1`` (libpano13 ``radial``/``inv_radial``; reference §1).

The polynomial is invertible on ``[0, rho_max)`` where ``rho_max`` is the smallest positive root of
``P'`` (libpano13 ``SetCorrectionRadius``; ``inf`` when there is none). Beyond it libpano13 returns
garbage (a scale of 1000, or 100 chaotic Newton steps); rigjax reports those points as invalid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

_NEWTON_STEPS_PER_CHECK = 4  # unrolled, so XLA fuses them into one pass over the points
_NEWTON_MAX_CHECKS = 10


def _d0(a, b, c):
    return 1.0 - a - b - c


def distortion_scale(a: ArrayLike, b: ArrayLike, c: ArrayLike, rho: ArrayLike) -> Float[Array, ...]:
    """``P(rho) / rho``: the factor that moves an ideal point to the source image (finite at 0)."""
    return ((a * rho + b) * rho + c) * rho + _d0(a, b, c)


def distort_radius(a: ArrayLike, b: ArrayLike, c: ArrayLike, rho: ArrayLike) -> Float[Array, ...]:
    """``P(rho)``: ideal normalised radius -> source-image normalised radius."""
    return rho * distortion_scale(a, b, c, rho)


def _dP(a, b, c, rho):
    return ((4.0 * a * rho + 3.0 * b) * rho + 2.0 * c) * rho + _d0(a, b, c)


def max_radius(a: ArrayLike, b: ArrayLike, c: ArrayLike) -> Float[Array, ...]:
    """Smallest positive root of ``P'`` (the end of the invertible range), ``inf`` if none.

    Closed form (Cardano / trigonometric), with the exact-zero degenerate branches of libpano13's
    ``cubeZero``/``squareZero``. No gradient flows through it: it only decides validity.
    """
    a, b, c = (jax.lax.stop_gradient(jnp.asarray(v)) for v in (a, b, c))
    a, b, c = jnp.broadcast_arrays(a, b, c)
    # P'(x) = A x^3 + B x^2 + C x + D
    A, B, C, D = 4.0 * a, 3.0 * b, 2.0 * c, _d0(a, b, c)
    inf = jnp.full_like(A, jnp.inf)

    def positive(root, exists):
        return jnp.where(exists & (root > 0.0), root, inf)

    # Cubic (A != 0), on x^3 + B' x^2 + C' x + D'.
    cubic = A != 0.0
    A_ = jnp.where(cubic, A, 1.0)
    Bn, Cn, Dn = B / A_, C / A_, D / A_
    p = (-(Bn * Bn) / 3.0 + Cn) / 3.0
    q = ((2.0 / 27.0) * Bn**3 - Bn * Cn / 3.0 + Dn) / 2.0
    disc = q * q + p * p * p
    one_real = disc >= 0.0
    sq = jnp.sqrt(jnp.where(one_real, disc, 0.0))
    r1 = jnp.cbrt(-q + sq) + jnp.cbrt(-q - sq) - Bn / 3.0
    neg_p = jnp.where(one_real, 1.0, -p)  # > 0 on the three-root branch
    phi = jnp.arccos(jnp.clip(-q / jnp.sqrt(neg_p**3), -1.0, 1.0))
    s = 2.0 * jnp.sqrt(neg_p)
    t1 = s * jnp.cos(phi / 3.0) - Bn / 3.0
    t2 = -s * jnp.cos(phi / 3.0 + jnp.pi / 3.0) - Bn / 3.0
    t3 = -s * jnp.cos(phi / 3.0 - jnp.pi / 3.0) - Bn / 3.0
    three = ~one_real
    cubic_root = jnp.minimum(
        positive(r1, one_real),
        jnp.minimum(positive(t1, three), jnp.minimum(positive(t2, three), positive(t3, three))),
    )

    # Quadratic (A == 0, B != 0).
    quad = B != 0.0
    B_ = jnp.where(quad, B, 1.0)
    qdisc = C * C - 4.0 * B * D
    has2 = qdisc >= 0.0
    qs = jnp.sqrt(jnp.where(has2, qdisc, 0.0))
    quad_root = jnp.minimum(positive((-C + qs) / (2.0 * B_), has2), positive((-C - qs) / (2.0 * B_), has2))

    # Linear (A == B == 0, C != 0); a constant has no positive root.
    lin = C != 0.0
    lin_root = positive(-D / jnp.where(lin, C, 1.0), lin)

    return jnp.where(cubic, cubic_root, jnp.where(quad, quad_root, jnp.where(lin, lin_root, inf)))


def _newton_tolerance(dtype) -> float:
    return 16.0 * float(jnp.finfo(dtype).eps)


def _accept_tolerance(dtype) -> float:
    # |P(rho) - rho_src| accepted as a solution (normalised radius; x R = pixels).
    return 1e-9 if jnp.finfo(dtype).bits >= 64 else 2e-5


@jax.custom_jvp
def _solve_radius(a, b, c, rho_src):
    tol = _newton_tolerance(rho_src.dtype)

    def newton_step(rho, done):
        f = distort_radius(a, b, c, rho) - rho_src
        done = done | (jnp.abs(f) <= tol)
        dp = _dP(a, b, c, rho)
        safe = jnp.where(dp != 0.0, dp, 1.0)
        return jnp.where(done | (dp == 0.0), rho, rho - f / safe), done

    def cond(state):
        check, _, done = state
        return (check < _NEWTON_MAX_CHECKS) & ~jnp.all(done)

    def body(state):
        check, rho, done = state
        for _ in range(_NEWTON_STEPS_PER_CHECK):
            rho, done = newton_step(rho, done)
        return check + 1, rho, done

    init = (jnp.asarray(0), rho_src, jnp.zeros(rho_src.shape, bool))
    _, rho, _ = jax.lax.while_loop(cond, body, init)
    return rho


@_solve_radius.defjvp
def _solve_radius_jvp(primals, tangents):
    # Implicit function theorem on P(rho; a, b, c) = rho_src (reference §4.7): the Newton loop
    # itself is never differentiated, so there is no dead zone in the derivative.
    a, b, c, rho_src = primals
    da, db, dc, drho_src = tangents
    rho = _solve_radius(a, b, c, rho_src)
    dp = _dP(a, b, c, rho)
    safe = jnp.where(dp != 0.0, dp, 1.0)
    # dP/da = rho^4 - rho, dP/db = rho^3 - rho, dP/dc = rho^2 - rho (d0 = 1 - a - b - c).
    dparams = (rho**4 - rho) * da + (rho**3 - rho) * db + (rho**2 - rho) * dc
    drho = jnp.where(dp != 0.0, (drho_src - dparams) / safe, 0.0)
    return rho, drho


def undistort_radius(
    a: ArrayLike, b: ArrayLike, c: ArrayLike, rho_src: ArrayLike, rho_max: ArrayLike | None = None
) -> tuple[Float[Array, ...], Bool[Array, ...]]:
    """Invert ``P``: source-image normalised radius -> ideal normalised radius.

    Newton's method from ``rho = rho_src`` (as libpano13's ``inv_radial``) iterated to machine
    precision instead of libpano13's absolute 1e-6, inside ``lax.while_loop``; derivatives come from
    the implicit function theorem. Returns ``(rho, valid)``; ``valid`` is False where ``rho_src``
    has no preimage in the invertible range ``[0, rho_max)``. ``rho_max`` is
    :func:`max_radius` of ``a, b, c``; a caller that has it per camera passes it in.
    """
    rho_src = jnp.asarray(rho_src)
    a, b, c = (jnp.asarray(v, rho_src.dtype) for v in (a, b, c))
    if rho_max is None:
        rho_max = max_radius(a, b, c)  # before broadcasting to the points
    a, b, c, rho_src = jnp.broadcast_arrays(a, b, c, rho_src)
    rho = _solve_radius(a, b, c, rho_src)
    residual = jnp.abs(distort_radius(a, b, c, rho) - rho_src)
    valid = (residual <= _accept_tolerance(rho_src.dtype)) & (rho >= 0.0) & (rho < rho_max) & jnp.isfinite(rho)
    return rho, valid
