"""Procedural textures: hashed value noise and the patterns of a street scene, in torch.

Everything is a pure function of coordinates (metres or unit directions) and an integer seed:
no random state is drawn while rendering, so a scene renders the same on every call, in any
chunking, on CPU. Integer hashing uses int64 arithmetic, whose wrap-around is exact.
"""

from __future__ import annotations

import torch
from torch import Tensor

_MASK32 = (1 << 32) - 1


def _hash(ix: Tensor, iy: Tensor, iz: Tensor, seed: int) -> Tensor:
    """Integer lattice point -> float in [0, 1) (a combination, then a 32-bit avalanche mix)."""
    h = (ix * 73856093 ^ iy * 19349663 ^ iz * 83492791 ^ seed * 2654435761) & _MASK32
    h = ((h >> 16) ^ h) * 0x7FEB352D & _MASK32
    h = ((h >> 15) ^ h) * 0x846CA68B & _MASK32
    h = (h >> 16) ^ h
    return (h & 0xFFFFFF).to(torch.float32) / float(1 << 24)


def cell_random(x: Tensor, y: Tensor, seed: int) -> Tensor:
    """A random value per unit cell of ``(x, y)``: constant within a cell (tiles, windows)."""
    ix = torch.floor(x).to(torch.int64)
    return _hash(ix, torch.floor(y).to(torch.int64), torch.zeros_like(ix), seed)


def _lerp(a: Tensor, b: Tensor, w: Tensor) -> Tensor:
    # Not torch.lerp, whose vectorised path may fuse a multiply-add and round differently from
    # its scalar path: the result must not depend on how torch splits the work.
    return a + w * (b - a)


def _fade(f: Tensor) -> Tensor:
    return f * f * (3.0 - 2.0 * f)


def value_noise(x: Tensor, y: Tensor, z: Tensor | None, seed: int) -> Tensor:
    """Smooth value noise in [0, 1) with unit lattice spacing: 3-D (trilinear), or 2-D (bilinear)
    when ``z`` is None. Smoothstep-faded."""
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = _fade(x - x0), _fade(y - y0)
    ix, iy = x0.to(torch.int64), y0.to(torch.int64)
    if z is None:
        iz, fz, layers = torch.zeros_like(ix), None, (0,)
    else:
        z0 = torch.floor(z)
        iz, fz, layers = z0.to(torch.int64), _fade(z - z0), (0, 1)
    out = torch.zeros_like(x)
    for dz in layers:
        plane = _lerp(
            _lerp(_hash(ix, iy, iz + dz, seed), _hash(ix + 1, iy, iz + dz, seed), fx),
            _lerp(_hash(ix, iy + 1, iz + dz, seed), _hash(ix + 1, iy + 1, iz + dz, seed), fx),
            fy,
        )
        out = plane if fz is None else (out + plane * (fz if dz else 1.0 - fz))
    return out


def fbm(x: Tensor, y: Tensor, z: Tensor | None, seed: int, octaves: int = 4) -> Tensor:
    """Fractal sum of ``octaves`` of value noise (each twice the frequency, half the amplitude), in
    [0, 1); 2-D when ``z`` is None."""
    total, amplitude, norm = torch.zeros_like(x), 1.0, 0.0
    for k in range(octaves):
        scale = float(2**k)
        total = total + amplitude * value_noise(x * scale, y * scale, None if z is None else z * scale, seed + 101 * k)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def stripes(u: Tensor, period: float, duty: float) -> Tensor:
    """1 where ``u mod period`` falls in the first ``duty`` fraction of the period, else 0."""
    return (torch.remainder(u, period) < duty * period).to(u.dtype)


def glyphs(u: Tensor, v: Tensor, seed: int) -> Tensor:
    """Text-like marks: rows of characters, each a 3 x 5 grid of random on/off cells.

    ``u`` runs along a line of text, ``v`` down the lines, both in character heights. Returns 1 on
    ink, 0 on the background.
    """
    char_u, char_v = u / 0.7, v / 1.4  # characters 0.7 wide, lines 1.4 apart (in heights)
    inside_u, inside_v = torch.remainder(char_u, 1.0), torch.remainder(char_v, 1.0)
    in_box = (inside_u < 0.8) & (inside_v < 0.72)
    cell_u = torch.floor(char_u) * 3 + torch.floor(inside_u / 0.8 * 3.0)
    cell_v = torch.floor(char_v) * 5 + torch.floor(inside_v / 0.72 * 5.0)
    on = cell_random(cell_u, cell_v, seed) < 0.45
    blank = cell_random(torch.floor(char_u), torch.floor(char_v), seed + 7) < 0.15  # spaces between words
    return (in_box & on & ~blank).to(u.dtype)
