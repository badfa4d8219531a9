"""Exposure, white balance and vignetting fitted in the overlaps: Hugin's photometric model
(:mod:`rigjax.camera.photometry`) for a calibrated rig.

Where two images see the same direction they record the same light, each through its own gain
``g = V(r) * 2^-Eev * (Er, 1, Eb)``. So at every sample of an overlap, per channel,

    log2 I_a - log2 I_b = [log2 V_a(r_a) - Eev_a + w_a] - [log2 V_b(r_b) - Eev_b + w_b]

(``w`` is ``log2 Er`` on red, 0 on green, ``log2 Eb`` on blue), a least-squares problem in each
image's ``Eev``, ``Er``, ``Eb`` and each lens's ``Vb``, ``Vc``, ``Vd`` (``Va`` and the centre
``Vx``, ``Vy`` stay as they are: ``Va`` trades with the exposure, the centre is the lens's). The
images say nothing of the rig's own exposure and white balance: the anchor's stay as they are.
Gauss-Newton in the log domain, the samples whose residual is far off the rest (parallax, a
moving object, a specular highlight) dropped after the first solve.

What the overlaps cannot tell is held and said: the vignetting of a lens whose overlaps sample one
radius only (a dual fisheye's seam ring) trades with its exposure. A lens's vignetting is kept only
where its standard deviation over the radii its samples span is at most ``max_vignetting_sd``; an image
that overlaps no other keeps its exposure and white balance. Where the fit's samples still disagree
by more than ``max_rms`` stops (RMS) once it has done its best, the overlaps do not show the same light
at the same directions (near content seen with parallax: a dual camera's own handlebars or
vehicle in its seams; a lens the matches left undetermined, which misplaces the circle's rim), and
what they say is not the cameras' gains: every letter is held as given, and said. Least squares on
such samples reads the colours of two different surfaces as a white balance.

Convention: pixel values are taken as linear in the light (Hugin's linear response), 0..255.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera.panorama import Equirect
from ..camera.photometry import radius_squared, vignetting_polynomial
from ..camera.trafo import transform_points
from ..errors import RigjaxError
from ..pto.project import Project

_SAMPLE_WIDTH = 512  # the panorama grid the overlaps are sampled on (pixels across 360 degrees)
_PER_PAIR = 8000  # at most this many samples of one pair (a random subset)
_SAMPLES = 120_000  # and of all pairs together (every frame's images of a turning camera: many pairs)
_DARK, _BRIGHT = 8.0, 247.0  # samples outside these (any channel) are dropped: noise, clipping
_STEPS = 10  # Gauss-Newton steps per solve
_OUTLIER_MADS = 4.0  # a sample this many (scaled) median deviations off is dropped after the first solve
_RADII = 21  # radii from 0 to the farthest a lens's samples reach, where its V(r) deviation is judged


@dataclass(frozen=True)
class ExposureFit:
    """What :func:`fit_exposure` found: ``project`` with the fitted letters; per image the
    standard deviations of ``Eev`` and of ``log2 Er``, ``log2 Eb`` (stops; NaN where held); per
    image the largest standard deviation of its vignetting ``V(r)`` over its radii (NaN where held);
    the samples used and their RMS residual (stops); and a line per letter held because the
    overlaps cannot tell it."""

    project: Project
    exposure_sd: np.ndarray
    white_balance_sd: np.ndarray  # (n_images, 2): red, blue
    vignetting_sd: np.ndarray
    samples: int
    rms: float
    held: tuple[str, ...]


@dataclass(frozen=True)
class _Samples:
    image: np.ndarray  # (n, 2) int: the two images of each sample
    radius2: np.ndarray  # (n, 2): r^2 of each end (half diagonals squared)
    log_ratio: np.ndarray  # (n, 3): log2 I_a - log2 I_b per channel


def overlap_samples(project: Project, images: Sequence[np.ndarray], seed: int = 0) -> _Samples:
    """Every pair of images' common directions on a panorama grid: the squared radius at each end
    (:func:`rigjax.camera.photometry.radius_squared`) and the log ratio of the two images' values
    (bilinear), where neither is dark or clipped; a random subset of each pair's, at most
    ``_PER_PAIR`` and ``_SAMPLES`` over all pairs."""
    n = len(project.images)
    if len(images) != n:
        raise RigjaxError(f"fit_exposure: {len(images)} images for a project of {n}")
    canvas = Equirect.create(_SAMPLE_WIDTH, _SAMPLE_WIDTH // 2, 360.0)
    x, y = np.meshgrid(np.arange(_SAMPLE_WIDTH, dtype=float), np.arange(_SAMPLE_WIDTH // 2, dtype=float))
    pano_xy = np.stack([x.ravel(), y.ravel()], axis=1)
    cameras = project.cameras(host=True)
    valid, values, radius2 = [], [], []
    for k, (image, pixels) in enumerate(zip(project.images, images)):
        if pixels.shape[:2] != (image.height, image.width):
            raise RigjaxError(
                f"fit_exposure: image {k} is {pixels.shape[1]}x{pixels.shape[0]}, its i line says "
                f"{image.width}x{image.height}"
            )
        out, ok = transform_points(cameras, canvas, np.full(len(pano_xy), k), pano_xy, reverse=True)
        ok = ok & (out[:, 0] >= 0) & (out[:, 0] <= image.width - 1) & (out[:, 1] >= 0) & (out[:, 1] <= image.height - 1)
        maps = np.where(ok[:, None], out, 0.0).astype(np.float32).reshape(_SAMPLE_WIDTH // 2, _SAMPLE_WIDTH, 2)
        sampled = cv2.remap(pixels, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR).reshape(-1, 3).astype(float)
        ok = ok & np.all((sampled > _DARK) & (sampled < _BRIGHT), axis=1)
        valid.append(ok)
        values.append(sampled)
        radius2.append(radius_squared(image, np.where(ok[:, None], out, 0.0)))
    rng = np.random.default_rng(seed)
    overlaps = {(a, b): np.flatnonzero(valid[a] & valid[b]) for a in range(n) for b in range(a + 1, n)}
    overlaps = {pair: both for pair, both in overlaps.items() if both.size}
    per_pair = min(_PER_PAIR, _SAMPLES // max(len(overlaps), 1))
    pairs, r2, ratios = [], [], []
    for (a, b), both in overlaps.items():
        both = rng.permutation(both)[:per_pair]
        pairs.append(np.tile([a, b], (both.size, 1)))
        r2.append(np.stack([radius2[a][both], radius2[b][both]], axis=1))
        ratios.append(np.log2(values[a][both]) - np.log2(values[b][both]))
    if not pairs:
        raise RigjaxError("fit_exposure: no two images see a common direction (no overlap to fit in)")
    return _Samples(np.concatenate(pairs), np.concatenate(r2), np.concatenate(ratios))


def _lens_groups(project: Project) -> list[int]:
    """Each image's vignetting group: the image whose ``Vb`` it links to, else its own."""
    return [image.links.get("Vb", k) for k, image in enumerate(project.images)]


def _layout(project: Project, anchor: int, white_balance: bool, fit_vignetting: set[int], seen: set[int]):
    """Column of each parameter: ``("e", k)`` Eev, ``("r", k)``/``("b", k)`` log2 Er/Eb, ``("v", g, j)``
    the vignetting coefficient j (Vb, Vc, Vd) of lens group g; only images in ``seen`` (in an
    overlap)."""
    columns = []
    for k in range(len(project.images)):
        if k != anchor and k in seen:
            columns.append(("e", k))
            if white_balance:
                columns += [("r", k), ("b", k)]
    for g in sorted(fit_vignetting):
        columns += [("v", g, j) for j in range(3)]
    return {key: i for i, key in enumerate(columns)}


def _values(project: Project) -> dict:
    """The letters the fit moves, as it parameterises them."""
    out = {}
    for k, image in enumerate(project.images):
        out[("e", k)] = image.exposure_value
        out[("r", k)] = math.log2(image.white_balance_red)
        out[("b", k)] = math.log2(image.white_balance_blue)
        out[("v", k, 0)], out[("v", k, 1)], out[("v", k, 2)] = (
            image.vignetting_b,
            image.vignetting_c,
            image.vignetting_d,
        )
    return out


def _residuals(values: dict, columns: dict, samples: _Samples, project: Project, groups: list[int]):
    """``(n, 3)`` residuals (stops) and their Jacobian ``(n, 3, params)``."""
    n = len(samples.image)
    model = np.zeros((n, 3))
    jac = np.zeros((n, 3, len(columns)))
    for end, sign in ((0, 1.0), (1, -1.0)):
        k = samples.image[:, end]
        r2 = samples.radius2[:, end]
        for image in np.unique(k):
            rows = np.flatnonzero(k == image)
            g = groups[image]
            va = project.images[image].vignetting_a
            vb, vc, vd = (values[("v", g, j)] for j in range(3))
            q = r2[rows]
            v = vignetting_polynomial(q, va, vb, vc, vd)
            if np.any(v <= 0.0):
                return None, None  # a vignetting that reaches 0 inside the image: the step is refused
            model[rows] += sign * (np.log2(v) - values[("e", image)])[:, None]
            model[rows, 0] += sign * values[("r", image)]
            model[rows, 2] += sign * values[("b", image)]
            if ("e", image) in columns:
                jac[rows, :, columns[("e", image)]] -= sign
            if ("r", image) in columns:
                jac[rows, 0, columns[("r", image)]] += sign
                jac[rows, 2, columns[("b", image)]] += sign
            for j in range(3):
                if ("v", g, j) in columns:
                    jac[rows, :, columns[("v", g, j)]] += (sign * q ** (j + 1) / (v * math.log(2.0)))[:, None]
    return samples.log_ratio - model, -jac


def _solve(values: dict, columns: dict, samples: _Samples, project: Project, groups: list[int]):
    """Gauss-Newton from ``values``; returns the values, the residuals and the Jacobian at the end."""
    values = dict(values)
    residuals, jac = _residuals(values, columns, samples, project, groups)
    if residuals is None:
        raise RigjaxError("fit_exposure: the start's vignetting reaches 0 inside an image")
    keys = sorted(columns, key=columns.get)
    for _ in range(_STEPS):
        flat_j, flat_r = jac.reshape(-1, len(columns)), residuals.reshape(-1)
        step = np.linalg.lstsq(flat_j, -flat_r, rcond=None)[0]
        for scale in (1.0, 0.5, 0.25, 0.125):  # halve a step that makes things worse
            trial = dict(values)
            for key, delta in zip(keys, step):
                trial[key] = values[key] + scale * delta
            new_r, new_j = _residuals(trial, columns, samples, project, groups)
            if new_r is not None and np.sum(new_r**2) <= np.sum(residuals**2):
                values, residuals, jac = trial, new_r, new_j
                break
        else:
            break
    return values, residuals, jac


def _vignetting_spread(cov: np.ndarray, columns: dict, group: int, reach: float) -> float:
    """The largest standard deviation of lens ``group``'s ``V(r)`` over the radii ``0..reach`` (half
    diagonals: where its samples lie; a circular fisheye's content ends near 0.71)."""
    index = [columns[("v", group, j)] for j in range(3)]
    radii = np.linspace(0.0, reach, _RADII)
    basis = np.stack([radii**2, radii**4, radii**6], axis=1)
    return float(np.sqrt(np.max(np.einsum("ri,ij,rj->r", basis, cov[np.ix_(index, index)], basis))))


def fit_exposure(
    project: Project,
    images: Sequence[np.ndarray],
    *,
    anchor: int = 0,
    white_balance: bool = True,
    vignetting_fit: bool = True,
    max_vignetting_sd: float = 0.02,
    max_rms: float | None = None,
    seed: int = 0,
) -> ExposureFit:
    """Each image's exposure value and white balance and each lens's vignetting, fitted in the
    overlaps of the calibrated ``project``'s ``images`` (module docstring). The anchor's exposure
    and white balance, every ``Va`` and the vignetting centres stay as they are; a lens's
    vignetting is its group's (images whose ``Vb`` links to one image share it). ``max_rms``
    (stops; None: no limit): a fit whose samples disagree more is not kept (``project`` returned as
    given, every standard deviation NaN, a line in ``held`` saying why)."""
    if not 0 <= anchor < len(project.images):
        raise RigjaxError(f"fit_exposure: anchor {anchor} is not an image of 0..{len(project.images) - 1}")
    if max_rms is not None and not max_rms > 0.0:
        raise RigjaxError(f"fit_exposure: max_rms must be > 0 stops (None: no limit), got {max_rms!r}")
    samples = overlap_samples(project, images, seed)
    groups = _lens_groups(project)
    start = _values(project)
    seen = set(np.unique(samples.image).tolist())
    held = [
        f"image {k}: overlaps no other image: its exposure and white balance held"
        for k in range(len(groups))
        if k not in seen
    ]
    fitted_lenses = {groups[k] for k in seen} if vignetting_fit else set()
    reach = {}  # how far from its vignetting centre each lens's samples lie, half diagonals
    for g in fitted_lenses:
        ends = np.isin(samples.image, [k for k, group in enumerate(groups) if group == g])
        reach[g] = float(np.sqrt(samples.radius2[ends].max()))
    while True:
        columns = _layout(project, anchor, white_balance, fitted_lenses, seen)
        values, residuals, _ = _solve(start, columns, samples, project, groups)
        # Drop what one gain per image cannot explain (parallax, motion), then solve again.
        per_sample = np.sqrt(np.mean(residuals**2, axis=1))
        limit = _OUTLIER_MADS * 1.4826 * np.median(per_sample) + 1e-3
        kept = per_sample <= limit
        inliers = _Samples(samples.image[kept], samples.radius2[kept], samples.log_ratio[kept])
        values, residuals, jac = _solve(values, columns, inliers, project, groups)
        flat_j = jac.reshape(-1, len(columns))
        dof = max(flat_j.shape[0] - flat_j.shape[1], 1)
        sigma2 = np.sum(residuals**2) / dof
        cov = sigma2 * np.linalg.pinv(flat_j.T @ flat_j)
        # A lens's vignetting the overlaps cannot tell: held, and the fit solved again without it.
        undetermined = []
        for g in sorted(fitted_lenses):
            spread = _vignetting_spread(cov, columns, g, reach[g])
            if not spread <= max_vignetting_sd:
                undetermined.append(g)
                held.append(
                    f"image {g}'s vignetting: its overlaps cannot tell it (V(r) known to ± {spread:.3f}, above "
                    f"{max_vignetting_sd:g}): held at Va..Vd as given"
                )
        if not undetermined:
            break
        fitted_lenses -= set(undetermined)
    n = len(project.images)
    exposure_sd, wb_sd, vig_sd = np.full(n, np.nan), np.full((n, 2), np.nan), np.full(n, np.nan)
    rms = float(np.sqrt(np.mean(residuals**2)))
    if max_rms is not None and not rms <= max_rms:
        line = (
            f"the overlaps disagree by {rms:.2f} stops (RMS) under the best gains (above {max_rms:g}): they do not "
            "show the same light at the same directions (near content seen with parallax, a lens the matches do "
            "not determine): every image's exposure, white balance and vignetting held as given"
        )
        return ExposureFit(project, exposure_sd, wb_sd, vig_sd, int(kept.sum()), rms, (*held, line))
    for k in range(n):
        if ("e", k) in columns:
            exposure_sd[k] = math.sqrt(cov[columns[("e", k)], columns[("e", k)]])
        if ("r", k) in columns:
            wb_sd[k] = [math.sqrt(cov[columns[(c, k)], columns[(c, k)]]) for c in "rb"]
        if ("v", groups[k], 0) in columns:
            vig_sd[k] = _vignetting_spread(cov, columns, groups[k], reach[groups[k]])
    fitted = []
    for k, image in enumerate(project.images):
        g = groups[k]
        fitted.append(
            image.replace(
                exposure_value=values[("e", k)],
                white_balance_red=2.0 ** values[("r", k)],
                white_balance_blue=2.0 ** values[("b", k)],
                vignetting_b=values[("v", g, 0)],
                vignetting_c=values[("v", g, 1)],
                vignetting_d=values[("v", g, 2)],
            )
        )
    return ExposureFit(
        project.replace(images=tuple(fitted)),
        exposure_sd,
        wb_sd,
        vig_sd,
        int(kept.sum()),
        rms,
        tuple(held),
    )


def format_exposure(fit: ExposureFit) -> str:
    """The fitted photometry per image, as ``rigjax calibrate`` prints it."""
    lines = [f"\nexposure and vignetting ({fit.samples} overlap samples, rms {fit.rms:.3f} stops):"]
    lines.append("image      Eev         Er         Eb     Vb       Vc       Vd   V(r) sd  file")
    for k, image in enumerate(fit.project.images):
        sd = fit.exposure_sd[k]
        held = "held" if np.isnan(sd) else f"±{sd:.3f}"
        vig = "held" if np.isnan(fit.vignetting_sd[k]) else f"{fit.vignetting_sd[k]:.4f}"
        lines.append(
            f"{k:>5} {image.exposure_value:+.3f} {held:>6} {image.white_balance_red:>8.4f} {image.white_balance_blue:>8.4f} "
            f"{image.vignetting_b:>+8.4f} {image.vignetting_c:>+8.4f} {image.vignetting_d:>+8.4f} {vig:>8}  "
            f"{image.filename}"
        )
    return "\n".join(lines + [f"note: {line}" for line in fit.held])
