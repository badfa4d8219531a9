"""The network's warps: corner offsets to homographies, homographies to sampling grids, and sampling
of equirectangular images that wraps around at +-180 degrees.

Convention: every grid is in ``grid_sample``'s normalised coordinates with ``align_corners=False``:
``x = -1`` is the left edge of pixel 0 and ``x = 1`` the right edge of pixel ``W - 1`` (the
panorama's longitude -180 and +180 degrees), likewise ``y`` from the top to the bottom edge. A
homography ``input_from_output`` maps an output (panorama) point to the point of the input canvas
it is sampled from: the identity samples each input where it already is.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

# The canvas corners, in the order kornia expects them: top-left, top-right, bottom-right, bottom-left.
_CORNERS = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))


def homographies_from_corners(offsets: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` homographies ``input_from_output`` that move the canvas corners by
    ``offsets`` ``(..., 4, 2)`` (normalised units), in closed form (kornia's four-point DLT on
    points already normalised to [-1, 1]). Zero offsets give the identity."""
    batch = offsets.shape[:-2]
    corners = torch.tensor(_CORNERS, dtype=offsets.dtype, device=offsets.device).expand(*batch, 4, 2)
    # kornia is imported where it is used: the full-resolution stitch never calls this, and the
    # import is a noticeable share of that command's start-up.
    from kornia.geometry.transform import get_perspective_transform

    flat = get_perspective_transform(corners.reshape(-1, 4, 2), (corners + offsets).reshape(-1, 4, 2))
    return flat.reshape(*batch, 3, 3)


def base_grid(height: int, width: int, *, dtype=torch.float32, device=None) -> torch.Tensor:
    """``(H, W, 2)`` normalised ``(x, y)`` of every pixel centre (``align_corners=False``)."""
    y = (torch.arange(height, dtype=dtype, device=device) + 0.5) / height * 2.0 - 1.0
    x = (torch.arange(width, dtype=dtype, device=device) + 0.5) / width * 2.0 - 1.0
    return torch.stack(torch.meshgrid(x, y, indexing="xy"), dim=-1)


def homography_grids(input_from_output: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """``(..., H, W, 2)`` sampling grids of homographies ``(..., 3, 3)`` over an ``H x W`` output.

    The homogeneous divide is guarded: with the model's bounded corner offsets (less than a
    quarter of the canvas) the canvas maps to a convex quadrilateral and ``w`` stays near 1; the
    clamp only keeps a diverging training step finite.
    """
    grid = base_grid(height, width, dtype=input_from_output.dtype, device=input_from_output.device)
    points = torch.cat([grid, torch.ones_like(grid[..., :1])], dim=-1)  # (H, W, 3)
    mapped = torch.einsum("...ij,hwj->...hwi", input_from_output, points)
    return mapped[..., :2] / mapped[..., 2:].clamp_min(1e-3)


def sample_wrapped(images: torch.Tensor, grid: torch.Tensor, wrap: float) -> torch.Tensor:
    """Bilinear samples of equirectangular ``images`` ``(N, C, H, W)`` at ``grid`` ``(N, h, w, 2)``.

    Horizontally the canvas wraps around: a grid ``x`` up to ``wrap`` (a fraction of the canvas
    width) beyond either edge reads the other side of the panorama. Further out, and above or
    below the canvas, samples are zero.
    """
    width = images.shape[-1]
    pad = math.ceil(wrap * width)
    if pad == 0:
        return F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    padded = F.pad(images, (pad, pad, 0, 0), mode="circular")
    # Pixel i of the original is pixel i + pad of the padded canvas: x' = x * W / (W + 2 pad).
    scale = torch.tensor([width / (width + 2 * pad), 1.0], dtype=grid.dtype, device=grid.device)
    return F.grid_sample(padded, grid * scale, mode="bilinear", padding_mode="zeros", align_corners=False)
