"""The template stitch: a fixed remap of each frame through the rig's calibration, no depth.

Every output pixel reads the cameras that see its direction at infinity, feather-blended as the
full-resolution renderer blends them (:func:`learnstitch.fullres.sight.views` at inverse depth 0),
so a template frame is the rotation-only stitch of the ``.pto``: what Hugin's ``nona`` with a fixed
template, FFmpeg's ``v360`` and the cameras' own apps do for video. The maps are made once per
rig; each frame is then a few OpenCV remaps of the decoded YUV 4:2:0 planes (no conversion to RGB
and back): the camera seen best at each pixel over the whole canvas, the others only in the
overlaps, where the blend needs them. Making the maps takes torch, JAX and a second or two; they
are kept in a cache (:func:`prepare_template`), so the next clip of the same rig starts at once.

Convention. The cameras' images lie side by side in one source plane, camera ``k`` from column
``x0_k`` (a side-by-side clip's frame as decoded; one file per camera, its planes joined), top
aligned; in Hugin's form of a dual-fisheye template every camera's image is the whole plane
(``x0_k = 0``, each kept to its crop's circle by the sight tables). Luma sample ``(x, y)`` is Hugin's image pixel ``(x, y)``; chroma sample ``(i, j)`` of
4:2:0 sits at luma ``(2 i, 2 j + 0.5)`` (H.264's and HEVC's default chroma siting, "left"), on
the output as on the input. Pixels no camera sees are black (``Y = 16, U = V = 128``). The
panorama is in the colour the caller gives (:mod:`learnstitch.video.colour`: the source's matrix,
BT.709 for an RGB source), each file's frame converted to it where it is in another.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import av
import cv2
import numpy as np

from .colour import Colour, tag, to_yuv420, yuv_planes

if TYPE_CHECKING:
    import rigjax

    from ..fullres.sight import SightTables

_BLACK = (16, 128, 128)  # limited-range black, per plane
_BAND_COLUMNS = 1024
_KEPT = 16  # templates the cache keeps, the most recently used
# The code a template's maps come from, by package: a change to any of it is another cache key.
_SOURCES = {"learnstitch": ("video/template.py", "fullres"), "rigjax": ("camera", "pto")}

Map = tuple[np.ndarray, np.ndarray]  # float32 (h, w) source x and y of each pixel: OpenCV remaps these fastest


class Layers(NamedTuple):
    """One plane's remap: ``primary`` the best-seen camera's map over the whole canvas; ``band``
    the flat indices ``(B,)`` of pixels two or more cameras see, laid out in rows of 1024 (the last
    padded); ``weights`` ``(rows, 1024)`` float32 of each camera that sees them there, by rank (0 in
    the padding and where a layer's camera does not see), and ``maps`` the map of each but the
    first: layer 0 is the best-seen camera, whose read the primary remap has made already."""

    primary: Map
    band: np.ndarray
    maps: list[Map]
    weights: list[np.ndarray]

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The layers as named arrays (:meth:`from_arrays` reads them back)."""
        out = {f"{prefix}primary{i}": a for i, a in enumerate(self.primary)} | {f"{prefix}band": self.band}
        out |= {f"{prefix}weight{rank}": weight for rank, weight in enumerate(self.weights)}
        for rank, xy in enumerate(self.maps, 1):
            out |= {f"{prefix}map{rank}_{i}": a for i, a in enumerate(xy)}
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix: str) -> Layers:
        ranks = sum(1 for name in arrays if name.startswith(f"{prefix}weight"))
        return cls(
            (arrays[f"{prefix}primary0"], arrays[f"{prefix}primary1"]),
            arrays[f"{prefix}band"],
            [(arrays[f"{prefix}map{r}_0"], arrays[f"{prefix}map{r}_1"]) for r in range(1, ranks)],
            [arrays[f"{prefix}weight{r}"] for r in range(ranks)],
        )


def _layers(
    tables: SightTables, x0: np.ndarray, width: int, height: int, subsample: int, chunk: int = 1 << 18
) -> Layers:
    """The remap of a plane ``subsample`` times smaller than the ``width x height`` luma canvas."""
    import torch

    from ..fullres.depth import pixel_rays
    from ..fullres.sight import views

    w, h = width // subsample, height // subsample
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    # Luma position of each sample (chroma siting), then the source plane's coordinates back.
    lx, ly = (xs * subsample).ravel(), (ys * subsample + (subsample - 1) / 2.0).ravel()
    count = tables.count
    coords, weight = np.empty((count, lx.size, 2), np.float32), np.empty((count, lx.size), np.float32)
    for start in range(0, lx.size, chunk):
        part = slice(start, start + chunk)
        rays = torch.from_numpy(pixel_rays(width, lx[part], ly[part])).float()
        seen = views(tables, rays, torch.zeros(rays.shape[0]))
        coords[:, part] = seen.xy.numpy()
        weight[:, part] = seen.feather.numpy()
    coords[..., 0] += x0[:, None]
    if subsample > 1:
        coords[..., 0] = coords[..., 0] / subsample
        coords[..., 1] = (coords[..., 1] - (subsample - 1) / 2.0) / subsample
    total = weight.sum(0)
    weight /= np.maximum(total, 1e-12)  # zero where no camera sees
    outside = np.float32(-1e4)  # reads the border value: black
    everywhere = np.arange(lx.size)
    best = weight.argmax(0)
    seen = total > 0
    primary = tuple(np.where(seen, coords[best, everywhere, i], outside).reshape(h, w) for i in (0, 1))
    band = np.flatnonzero((weight > 0).sum(0) >= 2)  # pixels two or more cameras see: blended
    order = np.argsort(-weight[:, band], axis=0, kind="stable")  # (N, B) their cameras by weight
    ranked = np.take_along_axis(weight[:, band], order, 0)
    layers = int((ranked > 0).sum(0).max()) if band.size else 0
    rows = -(-band.size // _BAND_COLUMNS)  # OpenCV remaps at most 32767 columns: the band as rows
    padding = (0, rows * _BAND_COLUMNS - band.size)
    maps, weights = [], []
    for rank in range(layers):
        weights.append(np.pad(ranked[rank], padding).astype(np.float32).reshape(rows, _BAND_COLUMNS))
        if rank == 0:  # the best-seen camera: the primary's read
            continue
        used, xy = ranked[rank] > 0, coords[order[rank], band]
        mx, my = (np.pad(np.where(used, xy[:, i], outside), padding, constant_values=outside) for i in (0, 1))
        maps.append((mx.reshape(rows, _BAND_COLUMNS), my.reshape(rows, _BAND_COLUMNS)))
    return Layers(primary, band, maps, weights)


def _remap(plane: np.ndarray, layers: Layers, black: int, out: np.ndarray) -> None:
    """``plane`` through ``layers`` into ``out`` (the canvas's plane, uint8)."""
    cv2.remap(plane, *layers.primary, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_CONSTANT, borderValue=black)
    if not layers.band.size:
        return
    # The band's layers blended in turn: each step a weighted mean (rounded) of the mean so far and
    # the next layer, weighted by their shares; within a level of the exact mean for 2 or 3 layers.
    # Layer 0, the best-seen camera, is what the primary remap wrote there.
    flat, so_far = out.reshape(-1), layers.weights[0]
    mixed = np.zeros(so_far.size, np.uint8)
    mixed[: layers.band.size] = flat[layers.band]
    mixed = mixed.reshape(so_far.shape)
    for rank, (maps, weight) in enumerate(zip(layers.maps, layers.weights[1:]), 2):
        read = cv2.remap(plane, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=black)
        mixed = cv2.blendLinear(mixed, read, so_far, weight)
        if rank < len(layers.weights):  # a layer follows: the shares blended so far
            so_far = so_far + weight
    flat[layers.band] = mixed.reshape(-1)[: layers.band.size]


class Template:
    """A rig's template stitch into ``width x width / 2`` panoramas (module docstring): its luma
    and chroma remaps. Make it with :func:`prepare_template` (through the cache) or :meth:`build`."""

    def __init__(self, width: int, luma: Layers, chroma: Layers):
        self.width, self.height, self.luma, self.chroma = width, width // 2, luma, chroma

    @classmethod
    def build(cls, tables: SightTables, sizes: Sequence[tuple[int, int]], width: int, shared: bool = False) -> Template:
        """The remaps through the cameras' sight tables, their images ``sizes`` ``(w_k, h_k)`` side
        by side in the source plane; ``shared``: each camera's image is the whole plane (Hugin's
        form of a dual-fisheye template, :mod:`learnstitch.video.source`)."""
        if width % 4:
            raise ValueError(f"the template stitch's width must be a multiple of 4, got {width}")
        x0 = np.concatenate([[0], np.cumsum([w for w, _ in sizes])[:-1]]).astype(np.float32)
        if shared:
            x0 = np.zeros_like(x0)
        return cls(width, *(_layers(tables, x0, width, width // 2, sub) for sub in (1, 2)))

    def save(self, path: Path) -> None:
        """Written under a temporary name and renamed: a reader finds the whole file or none."""
        partial = path.with_name(f"{path.name}.{os.getpid()}-{threading.get_ident()}.partial")
        with open(partial, "wb") as f:
            np.savez(f, width=self.width, **self.luma.arrays("luma_"), **self.chroma.arrays("chroma_"))
        os.replace(partial, path)

    @classmethod
    def load(cls, path: Path) -> Template:
        with np.load(path) as arrays:
            arrays = dict(arrays)
        return cls(int(arrays["width"]), Layers.from_arrays(arrays, "luma_"), Layers.from_arrays(arrays, "chroma_"))

    def __call__(self, frames: Sequence[av.VideoFrame], colour: Colour) -> av.VideoFrame:
        """The panorama of one rig frame (the decoded frames of its files, in order) as a YUV 4:2:0
        frame in ``colour`` (each file's frame converted to it where it is in another), tagged."""
        planes = [yuv_planes(to_yuv420(f, colour)) for f in frames]
        out = av.VideoFrame(self.width, self.height, "yuv420p")
        for p, (layers, black, view) in enumerate(zip((self.luma, self.chroma, self.chroma), _BLACK, yuv_planes(out))):
            source = planes[0][p] if len(planes) == 1 else _join([ps[p] for ps in planes])
            if view.flags.c_contiguous:
                _remap(source, layers, black, view)
            else:  # rows padded beyond the width: remapped beside, then copied in
                pixels = np.empty(view.shape, np.uint8)
                _remap(source, layers, black, pixels)
                view[...] = pixels
        return tag(out, colour)


def default_cache() -> Path | None:
    """``$LEARNSTITCH_CACHE_DIR/templates``, else ``$XDG_CACHE_HOME/learnstitch/templates``
    (``~/.cache/learnstitch/templates``); None where there is no home to put it in."""
    root = os.environ.get("LEARNSTITCH_CACHE_DIR")
    if not root:
        try:
            root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "learnstitch"
        except RuntimeError:  # no home directory
            return None
    return Path(root) / "templates"


def prepare_template(
    project: rigjax.Project,
    images: Sequence[np.ndarray],
    width: int,
    table_scale: float,
    cache: bool | str | os.PathLike = True,
    shared: bool = False,
) -> tuple[Template, bool]:
    """The template of ``project``'s rig at ``width`` (its sight tables ``table_scale`` times the
    width around), for image circles measured on ``images`` (the clip's first frame; to the
    pixel), and whether ``cache`` (a folder; True: :func:`default_cache`; False: none) held it;
    ``shared``: each camera's image is the clip's whole frame (:meth:`Template.build`). A template made here is kept
    there for the next clip of the same rig (the project's text, the sizes, the circles, the width
    and the code it comes from), the most recently used ``_KEPT`` at most: a hit needs neither
    torch nor JAX."""
    from ..fullres.rig import image_circles_px, image_crops

    sizes = [(int(i.width), int(i.height)) for i in project.images]
    circles = np.round(image_circles_px(project, images))
    key = hashlib.sha256(
        json.dumps(
            [
                project.to_text(),
                sizes,
                width,
                table_scale,
                [None if np.isnan(c) else c for c in circles.tolist()],
                shared,
            ]
        ).encode()
        + _source_digest()
    ).hexdigest()[:32]
    cache = default_cache() if cache is True else Path(cache) if cache else None
    path = None if cache is None else cache / f"{key}.npz"
    if path is not None and path.exists():
        try:
            template = Template.load(path)
        except Exception:  # unreadable (cut short, say): made again, and written over
            template = None
        if template is not None:
            with contextlib.suppress(OSError):  # another user's cache: read, not ours to touch
                os.utime(path)  # recently used
            return template, True
    from ..fullres.sight import sight_tables

    table_width = max(8, 2 * round(table_scale * width / 2))
    cameras = project.cameras(host=True)
    tables = sight_tables(
        cameras, np.zeros((len(sizes), 3)), table_width, circle_px=circles, crops=image_crops(project)
    )
    template = Template.build(tables, sizes, width, shared)
    if path is not None:
        try:
            cache.mkdir(parents=True, exist_ok=True)
            template.save(path)
            for stale in sorted(cache.glob("*.npz"), key=lambda p: p.stat().st_mtime, reverse=True)[_KEPT:]:
                stale.unlink(missing_ok=True)
            for orphan in cache.glob("*.partial"):  # a writer killed midway; an hour is past any write
                if time.time() - orphan.stat().st_mtime > 3600:
                    orphan.unlink(missing_ok=True)
        except OSError:
            pass  # a cache that cannot be written is no cache: the stitch goes on
    return template, False


@functools.cache
def _source_digest() -> bytes:
    import learnstitch
    import rigjax

    digest = hashlib.sha256()
    for package in (learnstitch, rigjax):
        root = Path(package.__file__).resolve().parent
        for source in _SOURCES[package.__name__]:
            found = root / source
            for path in sorted(found.rglob("*.py")) if found.is_dir() else [found]:
                digest.update(str(path.relative_to(root)).encode() + path.read_bytes())
    return digest.digest()


def _join(planes: list[np.ndarray]) -> np.ndarray:
    height = max(p.shape[0] for p in planes)
    return np.hstack([np.pad(p, ((0, height - p.shape[0]), (0, 0))) for p in planes])
