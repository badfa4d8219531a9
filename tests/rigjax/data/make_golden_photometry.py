#!/usr/bin/env python3
"""Record golden photometry from Hugin's ``nona`` (Debian package ``hugin-tools``).

Writes ``golden_photometry/flat.pto``, the float TIFF it names, and ``flat_nona.npz``: what ``nona``
renders of one flat image (the same value everywhere, per channel) through a project with an exposure
value, white balance, radial vignetting off-centre and a panorama exposure value. The images are
32-bit float and the response linear (``Rt1``), so nona's output is Hugin's photometric model alone
(``rigjax.camera.photometry``). ``make golden`` runs it.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).parent / "golden_photometry"
FLAT_RGB = (0.3, 0.5, 0.7)

PROJECT = """# hugin project file
#hugin_ptoversion 2
p f2 w96 h48 v360  k0 E0.5 R0 T"FLOAT" n"TIFF_m c:NONE"
m i0

# image lines
i w60 h40 f0 v100 Ra0 Rb0 Rc0 Rd0 Re0 Eev1.25 Er1.3 Eb0.8 r0 p0 y0 TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a0 b0 c0 d0 e0 g0 t0 Va1.1 Vb-0.45 Vc0.12 Vd-0.04 Vx6 Vy-3  Vm5 Rt1 n"flat.tif"

# specify variables that should be optimized
v

# control points

#hugin_optimizeReferenceImage 0
"""


def main() -> None:
    HERE.mkdir(exist_ok=True)
    (HERE / "flat.pto").write_text(PROJECT)
    flat = np.empty((40, 60, 3), np.float32)
    flat[:] = FLAT_RGB[::-1]  # OpenCV writes BGR
    cv2.imwrite(str(HERE / "flat.tif"), flat)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["nona", "-o", str(Path(tmp) / "out"), "-m", "TIFF_m", str(HERE / "flat.pto")], check=True)
        out = cv2.imread(str(Path(tmp) / "out0000.tif"), cv2.IMREAD_UNCHANGED)  # BGRA, alpha: covered
    rgba = np.concatenate([out[..., 2::-1], out[..., 3:]], axis=-1)
    np.savez_compressed(HERE / "flat_nona.npz", rgba=rgba.astype(np.float32))
    print(f"wrote {HERE}: {int((rgba[..., 3] > 0).sum())} covered panorama pixels")


if __name__ == "__main__":
    main()
