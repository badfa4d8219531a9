"""Stitching users' images with a trained network: two entry points, told apart by their names.

- :func:`stitch_project` (``learnstitch stitch --rig rig.pto -o pano.jpg [--width W]
  [--checkpoint model.pt | --sweep]``): any calibrated rig of two or more cameras at full
  resolution (:mod:`learnstitch.fullres`): the images the ``.pto`` names, the depth estimated at a
  working size (by the shipped network of any rig, another rig-aware network, or a plane sweep) and
  every input resampled at the output's size. :func:`prepare_project` does the part that depends on
  the rig alone, once, for a caller that stitches many frames of one rig.
- :func:`stitch_fisheyes` (``learnstitch stitch F0 F1 F2 --checkpoint model.pt [--rig rig.pto] -o
  pano.png``): fisheyes of the size a network was trained on, unwarped at the rig's nominal
  orientations or its calibration and stitched by the network at its own canvas size.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

import rigjax
from rigjax import Camera
from rigjax.errors import ConfigError

from .checkpoint import load_model
from .data.rig import nominal_centres, unwarp_grids
from .data.sample import SynthConfig, nominal_unwarp_grids, unwarp
from .data.store import write_depth, write_png
from .fullres.config import RenderConfig, render_with
from .fullres.rig import Rig, load_rig
from .fullres.stitcher import DepthSource, GivenDepth, NetworkDepth, PlaneSweep, Stitched, Stitcher
from .network.model import N_INPUTS

# The three-fisheye network (`learnstitch demo`'s triplets at its own size), and the network of any
# rig, what `learnstitch stitch --rig` reads a rig's depth with by default.
SHIPPED_MODEL = Path(__file__).parent / "weights" / "cpu_tiny_depth_d04.pt"
RIG_MODEL = Path(__file__).parent / "weights" / "cpu_tiny_anyrig.pt"


def read_fisheyes(paths: Sequence[str | Path]) -> tuple[torch.Tensor, list[Path]]:
    """``(3, 3, S, S)`` RGB in [0, 1] from three image files of one size."""
    paths = [Path(p) for p in paths]
    if len(paths) != N_INPUTS:
        raise ConfigError(
            f"expected {N_INPUTS} fisheye images (cameras at yaw 0, 120, 240), got {len(paths)}: {[str(p) for p in paths]}"
        )
    images = []
    for path in paths:
        image = rigjax.read_image(path)  # RGB; names the file it cannot read
        if images and image.shape[:2] != tuple(images[0].shape[-2:]):
            raise ConfigError(
                f"{path}: {image.shape[1]} x {image.shape[0]} pixels, but {paths[0]} is "
                f"{images[0].shape[-1]} x {images[0].shape[-2]}: the three fisheyes must have one size"
            )
        images.append(torch.from_numpy(image).permute(2, 0, 1).float() / 255.0)
    return torch.stack(images), paths


def stitch_fisheyes(
    model: torch.nn.Module,
    fisheyes: torch.Tensor,
    data: SynthConfig,
    cameras: Camera | None = None,
    centres: np.ndarray | torch.Tensor | None = None,
    *,
    circle_deg: float | None = None,
    source: str = "the fisheyes",
) -> torch.Tensor:
    """The network's panorama ``(3, H, W)`` at its own canvas size of fisheyes ``(N, 3, S, S)``
    (``S``: its ``data.fisheye_size``), unwarped at ``cameras`` (the rig's calibration; a model of
    ``model.inputs: calibrated`` needs them) or at the rig's design, stitched through the cameras'
    ``centres`` ``(N, 3)`` (world metres; a network of any rig needs them, a network of one rig
    defaults to its own); ``circle_deg``: the lenses' image circle (default ``data.circle_deg``; a
    sample of random rigs has its own); ``source`` names the images in errors."""
    size = data.fisheye_size
    if fisheyes.shape[-2:] != (size, size):
        raise ConfigError(
            f"{source}: {fisheyes.shape[-1]} x {fisheyes.shape[-2]} pixels; the model was trained on "
            f"{size} x {size} fisheyes (resize them, or train a config with that data.fisheye_size)"
        )
    if cameras is None and model.config.inputs == "calibrated":
        raise ConfigError(
            f"{source}: this model stitches fisheyes unwarped at the rig's calibration: pass the calibrated "
            "cameras (learnstitch stitch --rig rig.pto, as rigjax calibrate writes it)"
        )
    if cameras is not None and len(cameras.yaw) != fisheyes.shape[0]:
        raise ConfigError(f"{source}: {fisheyes.shape[0]} fisheyes, but the calibration has {len(cameras.yaw)} cameras")
    if cameras is None:
        grids, masks, _ = nominal_unwarp_grids(data)
    else:
        circle = data.circle_deg if circle_deg is None else circle_deg
        grids, masks, _ = unwarp_grids(cameras, (data.pano_width, data.pano_height), circle)
    device = next(model.parameters()).device
    rig = {}
    if centres is not None:
        rig["centres"] = torch.as_tensor(np.asarray(centres), dtype=torch.float32, device=device)[None]
    with torch.no_grad():
        out = model(unwarp(fisheyes, grids)[None].to(device), masks.float()[None].to(device), **rig)
    return out.pano[0].clamp(0.0, 1.0).cpu()


def stitch(
    model: torch.nn.Module,
    fisheyes: torch.Tensor,
    data: SynthConfig,
    source: str = "the fisheyes",
    cameras: Camera | None = None,
    centres: np.ndarray | torch.Tensor | None = None,
) -> torch.Tensor:
    """:func:`stitch_fisheyes` under its former name and argument order, kept for users' scripts,
    through the ``centres`` ``(N, 3)`` of the fisheyes' rig (a sample's ``rig.centres``): by default,
    for a network of one rig, the three-fisheye rig's nominal ones at ``data.distance``; a network
    of any rig refuses without them."""
    if centres is None and not getattr(model, "pooled", False):
        centres = nominal_centres(data.distance)
    return stitch_fisheyes(model, fisheyes, data, cameras, centres, source=source)


def rig_cameras(path: str | Path) -> tuple[Camera, np.ndarray | None]:
    """The three cameras of a calibrated rig's ``.pto`` (the images in the order of the fisheyes)
    and their centres ``(3, 3)`` (None where the project gives none)."""
    project = rigjax.load_project(path)
    cameras = project.cameras()
    if len(cameras.yaw) != N_INPUTS:
        raise ConfigError(f"{path}: {len(cameras.yaw)} images; the rig has {N_INPUTS} fisheyes")
    return cameras._replace(**{f: np.asarray(getattr(cameras, f)) for f in cameras._fields}), project.centres


def stitch_files(
    read: tuple[torch.Tensor, list[Path]],
    checkpoint: str | Path,
    output: str | Path,
    device: str = "cpu",
    rig: str | Path | None = None,
) -> torch.Tensor:
    """Three fisheyes stitched by the network of ``checkpoint`` at its own size (unwarped at the
    calibration ``rig`` for a model of ``model.inputs: calibrated``, through its centres or the
    rig's nominal ones), written to ``output``."""
    fisheyes, paths = read
    model, config = load_model(checkpoint, device=device)
    cameras, centres = (None, None) if rig is None else rig_cameras(rig)
    if centres is None:  # the three-fisheye rig's design
        centres = nominal_centres(config.data.distance)
    pano = stitch_fisheyes(model, fisheyes, config.data, cameras, centres, source=f"{paths[0]} (and the others)")
    write_png(Path(output), pano)
    return pano


def depth_source(
    model: str | Path | None, count: int, label: str, device: str | torch.device = "cpu"
) -> tuple[DepthSource, RenderConfig | None]:
    """Where a rig of ``count`` cameras (``label`` names its project) gets its working depth, and
    the render settings that come with it: ``model`` ``None``, the shipped network of any rig
    (:data:`RIG_MODEL`); ``"sweep"``, the plane sweep (no settings); a checkpoint's path, its
    rig-aware network (of any rig, or an error if the rig's camera count is not its), run on
    ``device``."""
    if model == "sweep":
        return PlaneSweep(), None
    path = RIG_MODEL if model is None else model
    loaded, trained = load_model(path, device=device)
    if trained.model.warp != "depth":
        raise ConfigError(
            f"{path}: not a rig-aware network (model.warp: {trained.model.warp}, not depth): it has no depth to "
            "stitch a rig through; pass a rig-aware checkpoint, or model='sweep' for the plane sweep"
        )
    if loaded.inputs not in (None, count):  # None: a network of any rig
        raise ConfigError(
            f"{label}: {count} cameras, but {path} stitches rigs of {loaded.inputs}; pass a network of any rig "
            "(the default) or model='sweep' for the plane sweep"
        )
    network = NetworkDepth(loaded, trained.data.pano_width, f"the rig-aware network {Path(path).name}")
    return network, trained.render


class PreparedProject(NamedTuple):
    """:func:`prepare_project`'s stitcher of a calibrated rig's frames, the rig (its first frame's
    images) and what it says about how it stitches (one line each)."""

    stitcher: Stitcher
    rig: Rig
    notes: list[str]


def prepare_project(
    project: rigjax.Project | str | Path,
    width: int | None = None,
    model: str | Path | None = None,
    *,
    images: Sequence[np.ndarray | str | Path] | None = None,
    config: RenderConfig | None = None,
    device: str | torch.device = "cpu",
    inverse_depth: np.ndarray | str | Path | None = None,
    render: dict | None = None,
) -> PreparedProject:
    """The part of :func:`stitch_project` that depends on the rig alone, done once: the project and
    its images read (:func:`~learnstitch.fullres.rig.load_rig`; ``images``, arrays or paths in the
    ``i`` lines' order, replace the files it names), the depth source loaded (``model``, run on
    ``device``, or ``inverse_depth``: see :func:`stitch_project`) and the sight tables made for
    panoramas ``width`` wide with the ``render:`` settings ``config`` (default the network's
    config's, or the defaults), ``render``'s keys replaced in them (``--render KEY=VALUE``)
    (:meth:`~learnstitch.fullres.stitcher.Stitcher.prepare`). Call the stitcher with each frame's
    images."""
    rig = load_rig(project, images)
    label = (project.path if isinstance(project, rigjax.Project) else str(project)) or "the project"
    notes = []
    if inverse_depth is not None:
        if model is not None:
            raise ConfigError("an inverse depth given replaces the network's or the sweep's: give no model with it")
        if not rig.has_centres:
            raise ConfigError(
                f"{label} gives no camera centres (#-rigjax centre lines): a depth changes nothing without them"
            )
        config = render_with(config or RenderConfig(), render)
        stitcher = Stitcher.prepare(rig, width, config)  # the width checked, then the depth against it
        stitcher.depth = GivenDepth(
            full=read_inverse_depth(inverse_depth, stitcher.width), label="the inverse depth given"
        )
        notes.append(f"depth given: {inverse_depth if isinstance(inverse_depth, (str, Path)) else 'an array'}")
        return PreparedProject(stitcher, rig, notes)
    if not rig.has_centres:
        notes.append(f"{label} gives no camera centres (#-rigjax centre lines): a rotation-only stitch")
    source: DepthSource = PlaneSweep()
    if rig.has_centres:
        source, settings = depth_source(model, len(rig.images), label, device)
        config = config or settings
        notes.append(f"depth from {source.label}")
    config = render_with(config or RenderConfig(), render)
    return PreparedProject(Stitcher.prepare(rig, width, config, source), rig, notes)


def read_inverse_depth(source: np.ndarray | str | Path, width: int) -> torch.Tensor:
    """A panorama's inverse depth ``(width / 2, width)`` float32 (1 / metres from the rig's centre,
    0 at infinity) from an array or a ``.npy`` file, checked: the panorama's size, finite, not
    negative. A :class:`ConfigError` names the file and what is wrong."""
    name = str(source) if isinstance(source, (str, Path)) else "the inverse depth"
    if isinstance(source, (str, Path)):
        try:
            source = np.load(source, allow_pickle=False)
        except OSError as error:
            raise ConfigError(f"{name}: cannot read it ({error.strerror or error})") from None
        except (ValueError, EOFError) as error:
            raise ConfigError(f"{name}: not a .npy array of inverse depths ({error})") from None
        if isinstance(source, np.lib.npyio.NpzFile):
            source.close()
            raise ConfigError(f"{name}: an .npz archive; give the inverse depth as one .npy array")
    values = np.asarray(source)
    height = width // 2
    if values.ndim != 2 or values.shape != (height, width):
        size = " x ".join(map(str, values.shape[::-1])) if values.ndim == 2 else f"of shape {values.shape}"
        raise ConfigError(
            f"{name}: an inverse depth {size}, the panorama {width} x {height} (its width asked for, or the .pto's "
            "p line's): give one of the panorama's size"
        )
    if not np.issubdtype(values.dtype, np.number) or np.iscomplexobj(values):
        raise ConfigError(f"{name}: inverse depths are real numbers (1 / metres), not {values.dtype}")
    with np.errstate(over="ignore"):  # a value beyond float32's range becomes inf: refused below
        values = values.astype(np.float32)
    bad = ~np.isfinite(values) | (values < 0)
    if bad.any():
        row, column = np.argwhere(bad)[0]
        raise ConfigError(
            f"{name}: {int(bad.sum())} inverse depths are not finite (as float32) or below 0 (the first at row "
            f"{row}, column {column}: {values[row, column]}): 1 / metres from the rig's centre, 0 at infinity"
        )
    return torch.from_numpy(values)


class ProjectStitch(NamedTuple):
    """:func:`stitch_project`'s panorama (:class:`learnstitch.fullres.stitcher.Stitched`), the rig it
    stitched and what it said about how (one line each: the depth's source, missing centres)."""

    stitched: Stitched
    rig: Rig
    notes: list[str]

    def summary(self, output: str | Path) -> str:
        """What ``learnstitch stitch --rig`` prints once the panorama is written to ``output``."""
        height, width = self.stitched.pano.shape[:2]
        timing = ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in self.stitched.seconds.items())
        done = f"{output}: {width} x {height} panorama of {len(self.rig.images)} cameras ({timing})"
        return "\n".join([*self.notes, done])


def stitch_project(
    project: rigjax.Project | str | Path,
    width: int | None = None,
    model: str | Path | None = None,
    *,
    keep_depth: bool = False,
    confidence: bool = False,
    **options,
) -> ProjectStitch:
    """The full-resolution panorama of a calibrated rig (:mod:`learnstitch.fullres`).

    ``project``: a ``.pto`` (path or :class:`rigjax.Project`) naming ``N >= 2`` images, with the
    cameras' centres in ``#-rigjax centre`` lines (none: a rotation-only stitch). ``width``: the
    panorama's (default the ``p`` line's), 2:1. ``model``: where the working-size depth comes from
    — ``None``, the shipped network of any rig (:data:`RIG_MODEL`); ``"sweep"``, the plane sweep; a
    checkpoint's path, its rig-aware network (of any rig, ``model.pooling: pooled``, or an error if
    the rig's camera count is not its). ``options``: :func:`prepare_project`'s keywords —
    ``images`` (replacing the files the project names), ``config`` (the ``render:`` settings;
    default the network's config's, or the defaults), ``device`` (where the network runs; the
    render runs on the CPU) and ``inverse_depth``: the panorama's own inverse depth, in place of
    ``model``'s — from a depth sensor, a scan or another model — an array ``(width / 2, width)`` or
    a ``.npy`` file of one, 1 / metres from the rig's centre, 0 at infinity
    (:func:`read_inverse_depth`), each input blended where it sees along its sight line to that depth.
    ``keep_depth``: the panorama comes with the inverse depth each pixel was rendered at
    (``stitched.rendered_depth``) and, where the depth was refined (:mod:`learnstitch.fullres.refine`),
    the refinement's confidence in it (``stitched.confidence``); ``confidence``: that confidence is
    wanted, and a stitch whose depth is not refined (a given ``inverse_depth``, ``render.refine_levels:
    0``, every centre at the origin) is refused before it stitches.
    """
    prepared = prepare_project(project, width, model, **options)
    if confidence and not prepared.stitcher.refines():
        raise ConfigError(
            "a confidence is the depth refinement's: this stitch does not refine its depth (a given inverse depth, "
            "render.refine_levels: 0, or every camera at the rig's centre)"
        )
    prepared.stitcher.keep_depth = keep_depth or confidence
    return ProjectStitch(prepared.stitcher.still(), prepared.rig, prepared.notes)


def stitch_project_to(
    project: rigjax.Project | str | Path,
    output: str | Path,
    width: int | None = None,
    model: str | Path | None = None,
    *,
    images: Sequence[np.ndarray | str | Path] | None = None,
    depth_output: str | Path | None = None,
    device: str | torch.device = "cpu",
    inverse_depth: np.ndarray | str | Path | None = None,
    confidence_output: str | Path | None = None,
    render: dict | None = None,
) -> ProjectStitch:
    """``learnstitch stitch --rig``: :func:`stitch_project`, the panorama written to ``output``
    (any format :func:`rigjax.write_image` writes) and to ``depth_output`` its depth: a ``.npy``
    gets the inverse depth each output pixel was rendered at, float32 at the panorama's size, 1 /
    metres from the rig's centre, 0 at infinity (what ``inverse_depth`` reads); an image, the
    working depth, near bright. ``confidence_output``: a ``.npy`` of the refinement's confidence in
    that depth, float32 at the panorama's size, in [0, 1] (0 where the inputs did not tell: one sees
    the point, or the colours agree as well at every depth tried). ``render``: ``render:`` keys
    replaced (:func:`prepare_project`)."""
    exact = depth_output is not None and Path(depth_output).suffix.lower() == ".npy"
    done = stitch_project(
        project,
        width,
        model,
        keep_depth=exact,
        confidence=confidence_output is not None,
        images=images,
        device=device,
        inverse_depth=inverse_depth,
        render=render,
    )
    rigjax.write_image(output, done.stitched.pano)
    if confidence_output is not None:
        np.save(confidence_output, done.stitched.confidence.numpy())
    if exact:
        np.save(depth_output, done.stitched.rendered_depth.numpy())
    elif depth_output is not None:
        write_depth(depth_output, done.stitched.inverse_depth)
    return done
