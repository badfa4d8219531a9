"""The demos ``learnstitch demo`` runs on built-in data: the shipped network on a synthetic test
triplet (:func:`demo`), a full-resolution rig written and stitched as a user's (:func:`fullres_demo`)
frames of a synthetic dual-fisheye camera for ``rigjax calibrate`` (:func:`dual_demo`) and a
clip of one for ``learnstitch stitch --video`` (:func:`video_demo`)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import torch

import rigjax

from .checkpoint import load_model
from .data.sample import SynthConfig, nominal_unwarp_grids
from .data.store import SPLIT_SEED_BASE, write_depth, write_png
from .fullres.stitcher import GivenDepth, stitch_rig
from .inference import RIG_MODEL, stitch_project


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
    with torch.no_grad():
        output = model(test.inputs[None], test.masks[None], centres=test.centres())
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
        "depth_oracle": stitch_rig(rig, depth=GivenDepth(full=inverse_depth, visibility=lines.visible)).pano,
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


def video_demo(out: str | Path, size: int = 960, frames: int = 45, seed: int = 0) -> str:
    """A clip of a synthetic dual-fisheye 360 camera carried through a street, as a user's camera
    records it (:mod:`learnstitch.data.sequence`: two 190-degree lenses ``size`` pixels each side
    by side, walking and turning, ``frames`` frames at 29.97 fps, H.264 with an AAC track), written
    to ``out/clip.mp4`` with its truth as ``truth.pto``. Returns the summary it prints: the commands
    that calibrate the clip and stitch it into a 360 video."""
    import av

    from .data.sequence import render_sequence, sequence_project

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clip, partial = out / "clip.mp4", out / "clip.partial.mp4"
    rate = Fraction(30000, 1001)
    samples = int(48000 * frames / rate)
    hum = (0.05 * np.sin(2 * np.pi * 110.0 * np.arange(samples + 1024) / 48000)).astype(np.float32)  # a street's
    with av.open(str(partial), "w", format="mp4") as container:
        video = container.add_stream("libx264", rate=rate, options={"crf": "16", "preset": "veryfast"})
        video.width, video.height, video.pix_fmt = 2 * size, size, "yuv420p"
        sound = container.add_stream("aac", rate=48000, layout="mono")
        heard = 0  # audio samples written, kept up with the frames
        for k, frame in enumerate(render_sequence("dual", seed, frames, size=size, pano_width=64)):
            picture = av.VideoFrame.from_ndarray(frame.side_by_side, format="rgb24")
            picture.pts = k
            container.mux(video.encode(picture))
            while heard < min(samples, (k + 1) * 48000 / rate):
                chunk = av.AudioFrame.from_ndarray(hum[None, heard : heard + 1024], format="fltp", layout="mono")
                chunk.sample_rate, chunk.pts = 48000, heard
                container.mux(sound.encode(chunk))
                heard += 1024
        container.mux(video.encode(None))
        container.mux(sound.encode(None))
    partial.replace(clip)
    sequence_project("dual", seed, size=size, pano_width=2 * size, names=("left.png", "right.png")).save(
        out / "truth.pto"
    )
    return "\n".join(
        [
            f"wrote {clip}: {frames} frames ({frames / float(rate):.1f} s) of a dual-fisheye camera walking and turning, "
            f"{2 * size} x {size}, with audio; its truth: {out / 'truth.pto'}",
            "calibrate it and stitch it into a 360 video with:",
            f"  rigjax calibrate --video {clip} --every 15 --frames 3 --template configs/rig/dual_fisheye.yaml "
            f"-o {out / 'rig.pto'}",
            f"  learnstitch stitch --rig {out / 'rig.pto'} --video {clip} -o {out / 'pano.mp4'}",
        ]
    )
