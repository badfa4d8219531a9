"""Procedural textures: hashed value noise and the patterns of a street scene, in torch.

Everything is a pure function of coordinates (metres or unit directions) and an integer seed:
no random state is drawn while rendering, so a scene renders the same on every call, in any
chunking, on CPU. Integer hashing is int32 arithmetic modulo 2**32, whose wrap-around is exact.
"""

from __future__ import annotations

import torch
from torch import Tensor

# Lattice hash: ``ix * P0 ^ iy * P1 ^ iz * P2 ^ seed * P_SEED``, then a 32-bit avalanche mix.
_P0, _P1, _P2, _P_SEED = 73856093, 19349663, 83492791, 2654435761


def _int32(value: int) -> int:
    """The signed 32-bit integer with the low 32 bits of ``value``."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value


def _shr(h: Tensor, bits: int) -> Tensor:
    """Logical right shift of int32 bit patterns (torch's ``>>`` is arithmetic on signed ints)."""
    return (h >> bits) & ((1 << (32 - bits)) - 1)


def _mix(h: Tensor) -> Tensor:
    """Combined lattice coordinates (int32) -> float in [0, 1)."""
    h = (_shr(h, 16) ^ h) * 0x7FEB352D
    h = (_shr(h, 15) ^ h) * _int32(0x846CA68B)
    h = _shr(h, 16) ^ h
    return (h & 0xFFFFFF).to(torch.float32) / float(1 << 24)


def _hash(ix: Tensor, iy: Tensor, iz: Tensor, seed: int) -> Tensor:
    """Integer lattice point (int32, :func:`_lattice`) -> float in [0, 1).

    Arithmetic modulo 2**32 on int32 bit patterns (products and sums wrap): CPUs multiply int32
    vectors natively, where int64 products are emulated.
    """
    return _mix(ix * _P0 ^ iy * _P1 ^ iz * _P2 ^ _int32(seed * _P_SEED))


def _lattice(floored: Tensor) -> Tensor:
    """Integer lattice coordinate of a floored float, as int32 holding its low 32 bits."""
    return floored.to(torch.int64).to(torch.int32)


def cell_random(x: Tensor, y: Tensor, seed: int) -> Tensor:
    """A random value per unit cell of ``(x, y)``: constant within a cell (tiles, windows)."""
    ix = _lattice(torch.floor(x))
    return _hash(ix, _lattice(torch.floor(y)), torch.zeros_like(ix), seed)


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
    ix, iy = _lattice(x0), _lattice(y0)
    if z is None:
        iz, fz, layers = None, None, (0,)
    else:
        z0 = torch.floor(z)
        iz, fz, layers = _lattice(z0), _fade(z - z0), (0, 1)
    # The lattice terms of the cell's corners, shared by its four (eight) hashes;
    # (i + 1) * P == i * P + P modulo 2**32.
    hx0, hy0 = ix * _P0, iy * _P1
    hx, hy = (hx0, hx0 + _P0), (hy0, hy0 + _P1)
    seed_term = _int32(seed * _P_SEED)
    out = torch.zeros_like(x)
    for dz in layers:
        hz = seed_term if z is None else (iz + dz) * _P2 ^ seed_term
        plane = _lerp(
            _lerp(_mix(hx[0] ^ hy[0] ^ hz), _mix(hx[1] ^ hy[0] ^ hz), fx),
            _lerp(_mix(hx[0] ^ hy[1] ^ hz), _mix(hx[1] ^ hy[1] ^ hz), fx),
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
