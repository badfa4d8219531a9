"""A procedural environment at infinity: an equirectangular texture with detail for features.

The texture is what synthetic rigs look at (:func:`rigjax.synthetic.render_images`): smooth colour
fields, several thousand random shapes (ellipses, polygons, strokes, glyphs) and fine grain. Shapes
are placed uniformly on the sphere and widened by ``1 / cos(latitude)``, so they look alike
wherever a camera points, including up and down; each is drawn twice, ``width`` apart, so the
texture has no seam at +-180 degrees.

Convention: row 0 is the top (latitude -90, looking up: rigjax's y axis points down), column 0 is
longitude -180; the texture is the canvas ``Equirect(width, width / 2, 360)``.
"""

from __future__ import annotations

import cv2
import numpy as np

_GLYPHS = "ABCDEFGHJKLMNPQRSTUVWXYZ0123456789#&%@"


def _smooth_noise(rng: np.random.Generator, height: int, width: int, cells: int, channels: int) -> np.ndarray:
    """Noise with ``cells`` cells around the horizon, cubic-interpolated and seamless at +-180."""
    grid = rng.uniform(0.0, 1.0, (max(cells // 2, 2), cells, channels)).astype(np.float32)
    pad = 2
    wrapped = np.concatenate([grid[:, -pad:], grid, grid[:, :pad]], axis=1)
    scale = width / cells
    big = cv2.resize(wrapped, (int(round(wrapped.shape[1] * scale)), height), interpolation=cv2.INTER_CUBIC)
    start = int(round(pad * scale))
    return big[:, start : start + width].reshape(height, width, channels)


def procedural_environment(width: int = 4096, *, seed: int = 0, shapes: int | None = None) -> np.ndarray:
    """A seeded ``(width / 2, width, 3)`` uint8 RGB equirectangular texture.

    ``shapes`` defaults to about one shape per 1,400 pixels (6,000 at width 4096).
    """
    if width < 64 or width % 2:
        raise ValueError(f"width must be an even number >= 64, got {width}")
    rng = np.random.default_rng(seed)
    height = width // 2
    base = 0.55 * _smooth_noise(rng, height, width, 6, 3) + 0.45 * _smooth_noise(rng, height, width, 24, 3)
    canvas = np.ascontiguousarray((base * 200 + 20).clip(0, 255).astype(np.uint8))
    n = shapes if shapes is not None else width * height // 1400
    unit = width / 360.0  # pixels per degree on the horizon
    for _ in range(n):
        lat = np.arcsin(rng.uniform(-0.99, 0.99))
        x, y = rng.uniform(0, width), (lat / np.pi + 0.5) * height
        stretch = 1.0 / np.cos(lat)
        size = unit * rng.uniform(0.25, 2.0)
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        kind = rng.integers(0, 4)
        for shift in (0.0, -width, width):
            cx = x + shift
            if not -width * 0.5 <= cx <= width * 1.5:
                continue
            if kind == 0:
                axes = (max(1, int(size * stretch)), max(1, int(size * rng.uniform(0.3, 1.0))))
                cv2.ellipse(
                    canvas, (int(cx), int(y)), axes, float(rng.uniform(0, 180)), 0, 360, colour, -1, cv2.LINE_AA
                )
            elif kind == 1:
                corners = rng.uniform(-size, size, (int(rng.integers(3, 6)), 2)) * [stretch, 1.0] + [cx, y]
                cv2.fillPoly(canvas, [corners.astype(np.int32)], colour, cv2.LINE_AA)
            elif kind == 2:
                end = rng.uniform(-2 * size, 2 * size, 2) * [stretch, 1.0] + [cx, y]
                cv2.line(
                    canvas, (int(cx), int(y)), (int(end[0]), int(end[1])), colour, int(rng.integers(1, 4)), cv2.LINE_AA
                )
            else:
                text = "".join(rng.choice(list(_GLYPHS), int(rng.integers(1, 4))))
                scale = size / 12.0
                (tw, th), base_line = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 2)
                patch = np.zeros((th + base_line + 2, tw + 2, 3), np.uint8)
                cv2.putText(patch, text, (1, th + 1), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 2, cv2.LINE_AA)
                patch = cv2.resize(patch, (max(1, int(patch.shape[1] * stretch)), patch.shape[0]))
                _paste(canvas, patch, int(cx), int(y))
    grain = rng.normal(0.0, 6.0, canvas.shape).astype(np.float32)
    return (canvas.astype(np.float32) + grain).clip(0, 255).astype(np.uint8)


def _paste(canvas: np.ndarray, patch: np.ndarray, cx: int, cy: int) -> None:
    """Paste a patch's non-black pixels centred at ``(cx, cy)``, clipped to the canvas."""
    h, w = patch.shape[:2]
    x0, y0 = cx - w // 2, cy - h // 2
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + w, canvas.shape[1]), min(y0 + h, canvas.shape[0])
    if xa >= xb or ya >= yb:
        return
    piece = patch[ya - y0 : yb - y0, xa - x0 : xb - x0]
    ink = piece.any(axis=-1)
    canvas[ya:yb, xa:xb][ink] = piece[ink]
