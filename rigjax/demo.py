"""``rigjax demo``: from synthetic fisheye images to a calibrated rig and a panorama.

The rig: six 1440x1080 full-frame fisheyes around the horizon (hfov 123, K2 -0.01, orientations a
couple of degrees off a regular ring), looking at a procedural environment at infinity, so the
truth is exact. The demo renders their images, calibrates them with the ``ring6`` template
(nominal hfov 120, K2 0, nominal ring orientations: SIFT, RANSAC, Lévy-flight starts, staged LM,
pruning), renders the panorama, and prints the recovered parameters against the truth.
"""

from __future__ import annotations

from pathlib import Path

from .calibration.pipeline import calibrate
from .calibration.template import load_template
from .rendering.blend import render
from .rendering.images import write_image
from .synthetic import align_to, environment_psnr, procedural_environment, ray_errors_arcmin, render_images, ring_rig


def run_demo(out: str | Path, template: str | Path = "configs/rig/ring6.yaml") -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    truth = ring_rig(orientation_jitter_deg=2.0, seed=1)
    environment = procedural_environment(4096, seed=0)
    images = render_images(truth, environment, noise_std=2.0, seed=0)
    names = [image.filename for image in truth.images]
    for name, image in zip(names, images):
        write_image(out / name, image)
    truth.save(out / "truth.pto")
    print(
        f"synthetic rig: 6 full-frame fisheyes 1440x1080 (hfov 123, K2 -0.01) around the horizon, "
        f"images in {out}/cam*.png, the true rig in {out / 'truth.pto'}"
    )
    config = load_template(template)
    print(f"template {template}: nominal hfov {config.rig.hfov:g}, K2 {config.rig.b:g}, ring orientations\n")
    calibration = calibrate(images, config, names=names)
    print(calibration.summary())
    path = out / "rig.pto"
    calibration.project.save(path)

    errors = ray_errors_arcmin(calibration.project, truth)
    header = f"{'cam':>3} {'hfov err':>9} {'K2 err':>9} {'max ray err arcmin':>19}"
    print(
        "\nagainst the truth (rays over a 24x24 raster of each image, after the one rotation of the whole rig\n"
        "that images at infinity cannot tell):"
    )
    print(header)
    print("-" * len(header))
    for k, (got, want) in enumerate(zip(calibration.project.images, truth.images)):
        print(f"{k:>3} {got.hfov - want.hfov:>9.4f} {got.b - want.b:>9.5f} {errors[k]:>19.3f}")
    # Turned as the truth (images at infinity cannot tell the rig's absolute orientation), so that
    # the panorama can be compared with the environment pixel for pixel.
    pano, covered = render(align_to(calibration.project, truth), images, width=2048, names=names)
    write_image(out / "panorama.jpg", pano)
    psnr = environment_psnr(pano, covered, environment, max_latitude_deg=37.0)  # the ring sees all longitudes there
    print(
        f"\nwrote {path} (open it in Hugin) and {out / 'panorama.jpg'}: PSNR {psnr:.2f} dB against the environment "
        "within +-37 degrees of the horizon"
    )
    print(f"try:  rigjax render {path} -o pano.png --width 4096")
