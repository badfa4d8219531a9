"""Stitching users' images with a trained network, and the demo with the model shipped in the package.

``learnstitch stitch --rig rig.pto -o pano.jpg [--width W] [--checkpoint model.pt | --sweep]``: any
calibrated rig of two or more cameras at full resolution (:func:`stitch_project`,
:mod:`learnstitch.fullres`): the images the ``.pto`` names, the depth estimated at a working size
(by the shipped network of any rig, another rig-aware network, or a plane sweep) and every input resampled
at the output's size.

``learnstitch stitch F0 F1 F2 --checkpoint model.pt [--rig rig.pto] -o pano.png``: three square
circular-fisheye images of the rig the checkpoint was trained for (cameras at yaw 0, 120 and 240
degrees, the size of its ``data.fisheye_size``), unwarped at the rig's nominal orientations — or,
for a model of ``model.inputs: calibrated``, at the cameras of the rig's calibration (``--rig``: a
``.pto`` of the three images, ``rigjax calibrate``'s output) — and stitched.
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
from .data.rig import unwarp_grids
from .data.sample import SynthConfig, nominal_unwarp_grids, unwarp
from .data.store import SPLIT_SEED_BASE, write_png
from .fullres.config import RenderConfig
from .fullres.depth import network_depth
from .fullres.render import Stitched, stitch_rig
from .fullres.rig import Rig, load_rig
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


def stitch(
    model: torch.nn.Module,
    fisheyes: torch.Tensor,
    data: SynthConfig,
    source: str = "the fisheyes",
    cameras: Camera | None = None,
) -> torch.Tensor:
    """The network's panorama ``(3, H, W)`` of fisheyes ``(3, 3, S, S)`` from the rig ``data``
    describes, unwarped at ``cameras`` (the rig's calibration; a model of ``model.inputs:
    calibrated`` needs them) or at the rig's design; ``source`` names the images in errors."""
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
    if cameras is None:
        grids, masks, _ = nominal_unwarp_grids(data)
    else:
        grids, masks, _ = unwarp_grids(cameras, (data.pano_width, data.pano_height), data.circle_deg)
    device = next(model.parameters()).device
    with torch.no_grad():
        out = model(unwarp(fisheyes, grids)[None].to(device), masks.float()[None].to(device))
    return out.pano[0].clamp(0.0, 1.0).cpu()


def rig_cameras(path: str | Path) -> Camera:
    """The three cameras of a calibrated rig's ``.pto`` (the images in the order of the fisheyes)."""
    cameras = rigjax.load_project(path).cameras()
    if len(cameras.yaw) != N_INPUTS:
        raise ConfigError(f"{path}: {len(cameras.yaw)} images; the rig has {N_INPUTS} fisheyes")
    return cameras._replace(**{f: np.asarray(getattr(cameras, f)) for f in cameras._fields})


def stitch_files(
    read: tuple[torch.Tensor, list[Path]],
    checkpoint: str | Path,
    output: str | Path,
    device: str = "cpu",
    rig: str | Path | None = None,
) -> torch.Tensor:
    """Three fisheyes stitched by the network of ``checkpoint`` at its own size (unwarped at the
    calibration ``rig`` for a model of ``model.inputs: calibrated``), written to ``output``."""
    fisheyes, paths = read
    model, config = load_model(checkpoint, device=device)
    cameras = None if rig is None else rig_cameras(rig)
    pano = stitch(model, fisheyes, config.data, source=f"{paths[0]} (and the others)", cameras=cameras)
    write_png(Path(output), pano)
    return pano


def demo(out: str | Path, seed: int = 0, checkpoint: str | Path = RIG_MODEL) -> str:
    """Stitch test sample ``seed`` of the three-fisheye rig with a shipped rig-aware network (by
    default the network of any rig, :data:`RIG_MODEL`, on its three-fisheye case; or that rig's own
    ``cpu_tiny`` model, :data:`SHIPPED_MODEL`); write the panoramas to ``out`` and return a summary
    with PSNR against the truth, beside the true-rotation and depth-oracle stitches'
    (:mod:`learnstitch.baselines`), over the whole panorama, the pixels some input sees, the near
    objects in the seams (seen, in two or more image circles, nearer than 2 m: sample 0's pole and
    the ground beside it) and those of them above the horizon (sample 0's pole)."""
    from .baselines import depth_oracle_stitch, psnr, rotation_only_stitch  # the references: the demo's alone
    from .evaluation import data_with, prepare_sample

    model, config = load_model(checkpoint)
    data = data_with(config.data, {"rig": "tri"})  # a network of any rig: its three-fisheye case
    grids, masks, _ = nominal_unwarp_grids(data)
    test = prepare_sample(data, SPLIT_SEED_BASE["test"] + seed, grids, masks, config.model.inputs)
    sample, seen = test.sample, test.regions["seen"]
    near, upper = test.near_seams(), test.near_seams(above_horizon=True)
    pooled = getattr(model, "pooled", False)  # a network of any rig takes the sample's centres
    rig = {"centres": torch.as_tensor(sample.rig.centres, dtype=torch.float32)[None]} if pooled else {}
    with torch.no_grad():
        output = model(test.inputs[None], test.masks[None], **rig)
    rotation_only, _ = rotation_only_stitch(sample.fisheyes, sample.rig, data)
    panos = {
        "network": output.pano[0].clamp(0.0, 1.0),
        "rotation_only": rotation_only,
        "depth_oracle": depth_oracle_stitch(sample.fisheyes, test.lines, data, rotation_only),
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, image in (*panos.items(), ("truth", sample.pano)):
        write_png(out / f"{name}.png", image)
    written = [f"{name}.png" for name in (*panos, "truth")]
    if output.inverse_depth is not None:  # the rig-aware network's depth, near bright
        scale = config.model.max_inverse_depth
        write_png(out / "inverse_depth.png", (output.inverse_depth[0] / scale).clamp(0.0, 1.0).expand(3, -1, -1))
        written.append("inverse_depth.png")
    labels = {
        "network": "network",
        "rotation_only": "true-rotation stitch (no parallax correction)",
        "depth_oracle": "depth oracle (the true depth: the best a warp can do)",
    }

    def scores(image: torch.Tensor) -> str:
        regions = [None, seen, *(where for where in (near, upper) if where.any())]
        return " / ".join(f"{float(psnr(image, sample.pano, where)):5.2f}" for where in regions)

    lines = [
        f"stitched test sample {seed} of {config.name}'s three-fisheye rig (d = {data.distance} m) with "
        f"{Path(checkpoint).name};",
        f"PSNR against the truth, whole panorama / pixels some input sees / near objects in the seams "
        f"({int(near.sum())} pixels nearer than 2 m) / those above the horizon ({int(upper.sum())} pixels):",
        *(f"  {scores(image)} dB  {labels[name]}" for name, image in panos.items()),
        f"panoramas in {out}/: {', '.join(written)}",
    ]
    return "\n".join(lines)


class ProjectStitch(NamedTuple):
    """:func:`stitch_project`'s panorama (:class:`learnstitch.fullres.render.Stitched`), the rig it
    stitched and what it said about how (one line each: the depth's source, missing centres)."""

    stitched: Stitched
    rig: Rig
    notes: list[str]


def stitch_project(
    project: rigjax.Project | str | Path,
    width: int | None = None,
    model: str | Path | None = None,
    *,
    images: Sequence[np.ndarray | str | Path] | None = None,
    config: RenderConfig | None = None,
    device: str | torch.device = "cpu",
) -> ProjectStitch:
    """The full-resolution panorama of a calibrated rig (:mod:`learnstitch.fullres`).

    ``project``: a ``.pto`` (path or :class:`rigjax.Project`) naming ``N >= 2`` images, with the
    cameras' centres in ``#-rigjax centre`` lines (none: a rotation-only stitch); ``images``
    replace the files it names. ``width``: the panorama's (default the ``p`` line's), 2:1.
    ``model``: where the working-size depth comes from — ``None``, the shipped network of any rig
    (:data:`RIG_MODEL`); ``"sweep"``, the plane sweep; a checkpoint's path, its rig-aware network
    (of any rig, ``model.pooling: pooled``, or an error if the rig's camera count is not its).
    ``config``: the ``render:`` settings (default the network's config's, or the defaults);
    ``device``: where the network runs (the render runs on the CPU).
    """
    rig = load_rig(project, images)
    label = (project.path if isinstance(project, rigjax.Project) else str(project)) or "the project"
    notes = []
    if not rig.has_centres:
        notes.append(f"{label} gives no camera centres (#-rigjax centre lines): a rotation-only stitch")
    working, depth_from = None, "the plane sweep"
    if rig.has_centres and model != "sweep":
        path = RIG_MODEL if model is None else model
        loaded, trained = load_model(path, device=device)
        count = len(rig.images)
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
        canvas = trained.data.pano_width

        def working(pyramid, tables, loaded=loaded, canvas=canvas):
            return network_depth(loaded, pyramid(canvas), tables, canvas)  # depth and blend weights

        depth_from = f"the rig-aware network {Path(path).name}"
        config = config or trained.render
    if rig.has_centres:
        notes.append(f"depth from {depth_from}")
    stitched = stitch_rig(rig, width, config, working_depth=working)
    return ProjectStitch(stitched, rig, notes)


def fullres_demo(out: str | Path, size: int = 1024, seed: int = 0) -> str:
    """The full-resolution path on a synthetic rig: three 185-degree fisheyes of ``size`` pixels
    0.4 m from the centre (:data:`learnstitch.data.rigs.FULLRES_RIGS` ``tri_d04``, the street scene
    of ``seed``, photometry as learnstitch's data has it) written to ``out`` as a user's rig would be
    (PNGs and their calibrated ``rig.pto``), stitched from there by :func:`stitch_project` with the
    shipped network of any rig into a panorama ``2 size`` wide, and scored beside the true-rotation stitch and
    the depth oracle (the same renderer and colour correction, through no depth and through the
    true one). Returns the summary it prints."""
    import dataclasses

    from .baselines import psnr
    from .data.rigs import FULLRES_RIGS, render_rig
    from .data.store import to_uint8
    from .data.visibility import rig_sight_lines

    shape = dataclasses.replace(FULLRES_RIGS["tri_d04"], size=size)
    width = 2 * size
    sample = render_rig(shape, seed, width, SynthConfig())
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = tuple(f"cam{k}.png" for k in range(len(shape.yaws)))
    for name, fisheye in zip(names, sample.fisheyes):
        rigjax.write_image(out / name, to_uint8(fisheye))
    sample.rig.project((width, size), names).save(out / "rig.pto")
    done = stitch_project(out / "rig.pto")
    rig = done.rig
    lines = rig_sight_lines(sample.scene, sample.rig.cameras, sample.rig.centres, sample.depth, shape.hfov)
    inverse_depth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
    panos = {
        "network": done.stitched.pano,
        "rotation_only": stitch_rig(rig._replace(centres=np.zeros_like(rig.centres))).pano,
        "depth_oracle": stitch_rig(rig, inverse_depth=inverse_depth, visibility=lines.visible).pano,
    }
    for name, pano in panos.items():
        rigjax.write_image(out / f"{name}.png", pano)
    rigjax.write_image(out / "truth.png", to_uint8(sample.pano))
    write_depth(out / "inverse_depth.png", done.stitched.inverse_depth)
    labels = {
        "network": "the network of any rig's depth at 256 x 128, full-resolution inputs",
        "rotation_only": "true-rotation stitch (no parallax correction)",
        "depth_oracle": "depth oracle (the true depth: the best a warp can do)",
    }
    timing = ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in done.stitched.seconds.items())

    def score(pano: np.ndarray, mask=None) -> float:
        return float(psnr(torch.from_numpy(pano).permute(2, 0, 1).float() / 255.0, sample.pano, mask))

    return "\n".join(
        [
            f"stitched a rig of three {size} x {size} fisheyes 0.4 m out into {width} x {size} with "
            f"learnstitch stitch --rig {out / 'rig.pto'} ({timing});",
            "PSNR against the truth, whole panorama / pixels some input sees:",
            *(
                f"  {score(pano):5.2f} / {score(pano, lines.seen):5.2f} dB  {labels[name]}"
                for name, pano in panos.items()
            ),
            f"in {out}/: the rig (cam*.png, rig.pto), {', '.join(f'{n}.png' for n in panos)}, truth.png, inverse_depth.png",
        ]
    )


def write_depth(path: str | Path, inverse_depth: torch.Tensor, max_inverse_depth: float | None = None) -> None:
    """An inverse depth map ``(h, w)`` as a grey image, near bright: ``q / max_inverse_depth``
    (default the map's own maximum) of full white."""
    top = float(inverse_depth.max()) if max_inverse_depth is None else max_inverse_depth
    grey = (inverse_depth / max(top, 1e-6)).clamp(0.0, 1.0)
    rigjax.write_image(path, (grey * 255.0 + 0.5).to(torch.uint8)[..., None].expand(-1, -1, 3).numpy())


def dual_demo(out: str | Path, size: int = 1440, frames: int = 3, seed: int = 0) -> str:
    """Frames of a synthetic dual-fisheye 360 camera for ``rigjax calibrate`` to calibrate
    (:mod:`learnstitch.data.dual`: two 190-degree fisheyes ``size`` pixels each, side by side, a
    near object in each seam, the camera turning 72 degrees a frame), written to ``out`` as a user's
    would be (``frame0.png`` ...), with the truth as ``truth.pto`` (camera 0's frame, as a
    calibration anchored on it reports the rig; its images the first frame's halves, written beside
    it). Returns the summary it prints: the truth and the commands that calibrate the frames."""
    from .data.dual import draw_dual, render_dual_frames

    truth = draw_dual(seed, size)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = [f"frame{f}.png" for f in range(frames)]
    for name, frame in zip(names, render_dual_frames(seed, truth, frames)):
        rigjax.write_image(out / name, frame)
        if name == names[0]:
            for half, pixels in (("left", frame[:, :size]), ("right", frame[:, size:])):
                rigjax.write_image(out / f"frame0-{half}.png", pixels)
    project = truth.project(("frame0-left.png", "frame0-right.png"))
    project.save(out / "truth.pto")
    lens, other = project.images
    frames_given = " ".join(str(out / name) for name in names)
    return "\n".join(
        [
            f"wrote {frames} side-by-side frames of a dual-fisheye camera ({size} x {size} per lens) to {out}/",
            f"the truth ({out / 'truth.pto'}): hfov {lens.hfov:.2f}, camera 1 at yaw {other.yaw:.2f}, pitch "
            f"{other.pitch:.2f}, roll {other.roll:.2f}, exposure {other.exposure_value:+.2f} EV, lenses "
            f"{100 * np.ptp(truth.centres[:, 2]):.1f} cm apart",
            "calibrate it with:",
            f"  rigjax calibrate {out / names[0]} --template configs/rig/dual_fisheye.yaml -o {out / 'rig.pto'}",
            f"  rigjax calibrate {frames_given} --template configs/rig/dual_fisheye.yaml -o {out / 'rig.pto'}",
        ]
    )
