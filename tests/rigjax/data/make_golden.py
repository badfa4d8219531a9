#!/usr/bin/env python3
"""Record golden transforms from Hugin's ``pano_trafo`` (Debian package ``hugin-tools``).

Writes, for each project below, ``golden/NAME.pto`` and ``golden/NAME.txt``. Each line of the
text file is ``dir image x_in y_in x_out y_out`` with ``dir`` ``f`` (image -> panorama) or ``r``
(panorama -> image), the output exactly as ``pano_trafo`` printed it. Points are seeded, so a
re-run with the same Hugin gives the same files. Standard library only: ``make golden``.
"""

from __future__ import annotations

import random
import subprocess
from pathlib import Path

HERE = Path(__file__).parent / "golden"
POINTS_PER_DIRECTION = 40  # per image


def i_line(w, h, f, v, y=0.0, p=0.0, r=0.0, a=0.0, b=0.0, c=0.0, d=0.0, e=0.0, name="img.jpg", links=None):
    """An i line as Hugin 2022 writes it; ``links`` maps a letter to ``"=K"``."""
    links = links or {}
    val = {"v": v, "y": y, "p": p, "r": r, "a": a, "b": b, "c": c, "d": d, "e": e}
    t = {k: f"{k}{links.get(k, repr(float(x)).removesuffix('.0'))}" for k, x in val.items()}
    return (
        f"i w{w} h{h} f{f} {t['v']} Ra0 Rb0 Rc0 Rd0 Re0 Eev0 Er1 Eb1 {t['r']} {t['p']} {t['y']} "
        f"TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 {t['a']} {t['b']} {t['c']} {t['d']} {t['e']} g0 t0 "
        f'Va1 Vb0 Vc0 Vd0 Vx0 Vy0  Vm5 n"{name}"'
    )


def project(pano, images):
    w, h, v = pano
    lines = [
        "# hugin project file",
        "#hugin_ptoversion 2",
        f'p f2 w{w} h{h} v{v}  k0 E0 R0 n"TIFF_m c:LZW r:CROP"',
        "m i0",
        "",
        "# image lines",
    ]
    for image in images:
        lines += ["#-hugin  cropFactor=1", image]
    lines += [
        "",
        "# specify variables that should be optimized",
        "v",
        "",
        "#hugin_optimizeReferenceImage 0",
        "#hugin_optimizerMasterSwitch 0",
        "#hugin_optimizerPhotoMasterSwitch 0",
    ]
    return "\n".join(lines) + "\n"


CUBE = [(0, 0), (90, 0), (180, 0), (-90, 0), (0, 90), (0, -90)]

PROJECTS = {
    # full-frame fisheye, landscape, the reference's example lens
    "ff_landscape": ((3600, 1800, 360), [i_line(4000, 3000, 3, 165, y=12.5, p=-7.25, r=3.5, b=-0.02)]),
    # full-frame fisheye, portrait, all of a-e, large angles
    "ff_portrait_abcde": (
        (2000, 1000, 360),
        [i_line(1080, 1440, 3, 123, y=-135, p=40, r=-170, a=0.01, b=-0.05, c=0.02, d=12, e=-7)],
    ),
    # circular fisheye beyond 180 degrees, shifted centre, roll 90
    "circular_185": ((3000, 1500, 360), [i_line(1920, 1920, 2, 185, y=120, p=-10, r=90, b=-0.03, d=5, e=3)]),
    # circular fisheye looking almost straight up
    "circular_zenith": ((2400, 1200, 360), [i_line(3000, 3000, 2, 200, y=-60, p=85, r=15, a=-0.01, b=0.02)]),
    # rectilinear, landscape, all of a-e
    "rect_landscape_abcde": (
        (4000, 2000, 360),
        [i_line(6000, 4000, 0, 70, y=170, p=-30, r=5, a=0.001, b=-0.01, c=0.005, d=30, e=-20)],
    ),
    # rectilinear portrait on a partial, non-2:1 canvas
    "rect_portrait_partial": ((1000, 800, 200), [i_line(3000, 4000, 0, 50, y=-45, p=60, r=-90)]),
    # equirectangular input
    "equirect_full": ((3600, 1800, 360), [i_line(4000, 2000, 4, 360, y=30, p=10, r=-20)]),
    "equirect_partial_abde": (
        (2000, 1000, 360),
        [i_line(2000, 1000, 4, 180, y=-20, p=-5, r=2, a=0.002, b=-0.01, d=8, e=-4)],
    ),
    # stereographic, equisolid, orthographic
    "stereographic": ((3000, 1500, 360), [i_line(2000, 1500, 10, 140, y=-90, p=-45, r=30, b=-0.01)]),
    "equisolid_abcde": (
        (3000, 1500, 360),
        [i_line(1500, 2000, 21, 150, y=10, p=-100, r=170, a=0.02, b=-0.04, c=0.01, d=-15, e=9)],
    ),
    "orthographic": ((2000, 1000, 360), [i_line(2000, 2000, 8, 160, y=45, p=20, r=-10)]),
    # strong barrel distortion: the polynomial's invertible range ends inside the frame
    "ff_strong_barrel": ((3000, 1500, 360), [i_line(2000, 1500, 3, 180, y=5, p=-3, r=1, b=-0.15)]),
    # a 6-camera cube rig of portrait fisheyes with a shared lens (v, b linked to image 0)
    "cube_rig_linked": (
        (3600, 1800, 360),
        [
            i_line(
                1080,
                1440,
                3,
                123 if k == 0 else 0,
                y=y,
                p=p,
                r=(7 * k) % 11 - 5,
                b=-0.03 if k == 0 else 0,
                name=f"cam{k}.jpg",
                links={} if k == 0 else {"v": "=0", "b": "=0"},
            )
            for k, (y, p) in enumerate(CUBE)
        ],
    ),
    # near gimbal lock, odd canvas size with hfov < 360
    "gimbal_odd_canvas": ((1001, 501, 300), [i_line(1600, 1200, 3, 190, y=179.9, p=-89.99, r=-179.99, b=0.01)]),
}


def run(pto: Path, lines: list[str], reverse: bool) -> list[str]:
    cmd = ["pano_trafo"] + (["-r"] if reverse else []) + [str(pto)]
    out = subprocess.run(cmd, input="".join(lines), capture_output=True, text=True, check=True).stdout
    result = out.split("\n")[: len(lines)]
    if len(result) != len(lines):
        raise RuntimeError(f"{pto}: pano_trafo returned {len(result)} lines for {len(lines)} points")
    return result


def main() -> None:
    HERE.mkdir(parents=True, exist_ok=True)
    for seed, (name, (pano, images)) in enumerate(sorted(PROJECTS.items())):
        rng = random.Random(seed)
        pto = HERE / f"{name}.pto"
        pto.write_text(project(pano, images))
        rows = []
        for k, image in enumerate(images):
            tokens = dict((t[0], t[1:]) for t in image.split() if t[0] in "wh")
            w, h = int(tokens["w"]), int(tokens["h"])
            fwd = [(w / 2 - 0.5, h / 2 - 0.5), (-0.5, -0.5), (w - 0.5, h - 0.5), (w - 0.5, -0.5)]
            fwd += [(rng.uniform(-0.5, w - 0.5), rng.uniform(-0.5, h - 0.5)) for _ in range(POINTS_PER_DIRECTION - 4)]
            rev = [(pano[0] / 2 - 0.5, pano[1] / 2 - 0.5)]
            rev += [
                (rng.uniform(-0.5, pano[0] - 0.5), rng.uniform(-0.5, pano[1] - 0.5))
                for _ in range(POINTS_PER_DIRECTION - 1)
            ]
            for tag, points, reverse in (("f", fwd, False), ("r", rev, True)):
                inputs = [f"{k} {x:.6f} {y:.6f}\n" for x, y in points]
                for line, out in zip(inputs, run(pto, inputs, reverse)):
                    rows.append(f"{tag} {line.strip()} {out.strip()}")
        (HERE / f"{name}.txt").write_text(
            f"# pano_trafo golden data for {name}.pto: dir image x_in y_in x_out y_out\n" + "\n".join(rows) + "\n"
        )
        print(f"{name}: {len(images)} image(s), {len(rows)} points")


if __name__ == "__main__":
    main()
