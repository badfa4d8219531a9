"""Photometric calibration from the overlaps (``model.photometry: fitted``): each input's exposure
and the lens's vignetting, fitted in closed form for every panorama, as Hugin's photometric
optimiser does for a project, instead of gain maps a network paints.

Model. An input records radiance ``L`` seen at normalised lens radius ``r`` (the ray's angle from
the lens axis over the image circle's half-angle: 0 at the centre, 1 at the circle's edge) as

    I_i = exp(e_i) V(r) L,        log V(r) = b r^2 + c r^4

with ``e_i`` input ``i``'s log exposure and one vignetting curve ``(b, c)`` for the rig's lens.
Where inputs ``i`` and ``j`` see the same scene point, ``L`` cancels:

    log I_i - log I_j = e_i - e_j + b (r_i^2 - r_j^2) + c (r_i^4 - r_j^4)

linear in ``(e, b, c)``. The fit sums these equations over every pair's overlapping pixels
(luminance, away from black and saturated values), solves the weighted normal equations and
reweights by a Cauchy function of the residuals (points the alignment leaves apart are outliers),
with the exposures' mean held at 0 (the panorama keeps the inputs' average exposure, which no
overlap can tell) and a small ridge on ``(b, c)`` (a rig with little overlap keeps ``V = 1``). The
correction divides each input by ``exp(e_i) V(r)``. A photometrically clean rig fits ``e = 0`` and
``V = 1`` up to noise: nothing to brighten.

Lens radius without the lens model: an input unwarped onto the panorama canvas covers its image
circle, a spherical cap around its lens axis. The cap's mean direction (weighted by each canvas
pixel's solid angle) is the axis, and its solid angle ``2 pi (1 - cos a)`` gives the half-angle
``a``: :func:`lens_radius` needs the masks and the canvas rays only, at any orientation.
"""

from __future__ import annotations

import torch

# Pixels taking part: both inputs whole there (bilinear samples off a mask's edge excluded), and
# luminance in [_DARK, _BRIGHT] (log of noise near black; clipped values near white).
_WHOLE, _DARK, _BRIGHT = 0.999, 0.03, 0.97
# Cauchy scale of the reweighting (log-luminance units) and its iterations after a plain fit.
_CAUCHY_SCALE, _REWEIGHTS = 0.05, 4
# Ridge on the vignetting coefficients and exposures, relative to the total weight of the data.
_VIGNETTING_RIDGE, _EXPOSURE_RIDGE = 1e-3, 1e-6
# Bound of the correction factor: a wrong fit can never darken or brighten by more.
_MAX_FACTOR = 2.0


def lens_radius(masks: torch.Tensor, rays: torch.Tensor) -> torch.Tensor:
    """``(B, N, H, W)`` normalised lens radius of every canvas pixel for inputs with image-circle
    masks ``(B, N, H, W)`` on an equirectangular canvas of unit rays ``(H, W, 3)``; see the module
    docstring. Convention: 0 on the lens axis, 1 at the circle's edge (larger outside it)."""
    masks = masks.float()
    rays = rays.to(masks)
    area = torch.hypot(rays[..., 0], rays[..., 2])  # a canvas pixel's solid angle is proportional to cos(lat)
    weight = masks * area
    axis = torch.einsum("bnhw,hwi->bni", weight, rays)
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    pixel = (2.0 * torch.pi / rays.shape[1]) * (torch.pi / rays.shape[0])  # dlon * dlat
    solid_angle = weight.sum(dim=(-2, -1)) * pixel
    half_angle = torch.arccos((1.0 - solid_angle / (2.0 * torch.pi)).clamp(-1.0, 1.0)).clamp_min(1e-6)
    angle = torch.arccos(torch.einsum("hwi,bni->bnhw", rays, axis).clamp(-1.0, 1.0))
    return angle / half_angle[..., None, None]


def fit_photometry(
    rgb: torch.Tensor, alpha: torch.Tensor, radius: torch.Tensor, present: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Exposures ``(B, N)`` and vignetting coefficients ``(B, 2)`` (``b, c``) of aligned inputs.

    ``rgb`` ``(B, N, 3, H, W)``: the inputs warped onto the panorama (premultiplied by their masks,
    as the inputs are); ``alpha`` ``(B, N, H, W)``: the warped masks; ``radius`` ``(B, N, H, W)``:
    each input's :func:`lens_radius` warped the same way; ``present`` ``(B, N)`` bool: the inputs
    that exist (a batch of rigs of several sizes pads the smaller ones with absent inputs, whose
    exposure is held at 0 and left out of the mean; default all). No gradient: a measurement.
    """
    with torch.no_grad():
        n = alpha.shape[1]
        rgb, alpha, radius = rgb.double(), alpha.double(), radius.double()
        luminance = rgb.mean(dim=2) / alpha.clamp_min(1e-6)
        usable = (alpha > _WHOLE) & (luminance > _DARK) & (luminance < _BRIGHT)
        log_l = luminance.clamp_min(_DARK).log()
        rows, targets, weights = [], [], []
        eye = torch.eye(n, dtype=torch.float64, device=rgb.device)
        for i in range(n):
            for j in range(i + 1, n):
                r2 = radius[:, i] ** 2, radius[:, j] ** 2
                features = torch.stack([r2[0] - r2[1], r2[0] ** 2 - r2[1] ** 2], dim=-1)  # (B, H, W, 2)
                exposure = (eye[i] - eye[j]).expand(*features.shape[:-1], n)
                rows.append(torch.cat([exposure, features], dim=-1).flatten(1, 2))
                targets.append((log_l[:, i] - log_l[:, j]).flatten(1))
                weights.append((usable[:, i] & usable[:, j]).double().flatten(1))
        a = torch.cat(rows, dim=1)  # (B, pixels x pairs, N + 2)
        y, w0 = torch.cat(targets, dim=1), torch.cat(weights, dim=1)
        total = w0.sum(dim=1)[:, None, None] + 1.0
        ridge = torch.tensor([_EXPOSURE_RIDGE] * n + [_VIGNETTING_RIDGE] * 2, dtype=torch.float64, device=rgb.device)
        exists = torch.ones_like(alpha[:, :, 0, 0]) if present is None else present.to(alpha)
        prior = torch.diag(ridge).repeat(len(exists), 1, 1)
        # (sum of the present inputs' exposures)^2: their mean held at 0; an absent one's held at 0.
        prior[:, :n, :n] += exists[:, :, None] * exists[:, None, :] + torch.diag_embed(1.0 - exists)
        prior = prior * total
        w = w0
        for _ in range(_REWEIGHTS + 1):
            normal = torch.einsum("bpi,bp,bpj->bij", a, w, a) + prior
            theta = torch.linalg.solve(normal, torch.einsum("bpi,bp,bp->bi", a, w, y))
            residual = y - torch.einsum("bpi,bi->bp", a, theta)
            w = w0 / (1.0 + (residual / _CAUCHY_SCALE) ** 2)
        return theta[:, :n].float(), theta[:, n:].float()


def correction(exposure: torch.Tensor, vignetting: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
    """``(B, N, ...)`` factors ``1 / (exp(e_i) V(r))`` that undo the fitted exposures ``(B, N)`` and
    vignetting ``(B, 2)`` at lens radii ``(B, N, ...)``, bounded to ``[1/2, 2]``. Outside the
    image circle (``r > 1``) the curve is held at its edge value."""
    r2 = radius.clamp(max=1.0) ** 2
    extra = (1,) * (radius.ndim - 2)
    b, c = (v.reshape(-1, 1, *extra) for v in vignetting.unbind(-1))
    log_factor = -(exposure.reshape(*exposure.shape, *extra) + b * r2 + c * r2 * r2)
    return log_factor.exp().clamp(1.0 / _MAX_FACTOR, _MAX_FACTOR)
