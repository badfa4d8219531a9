"""The stitching network.

``warp`` (homographies from corner offsets, sampling across the panorama's seam), ``model``
(:class:`StitchNet`: homographies, displacement map and weight maps per input) and ``losses``
(L1, SSIM and VGG-16 perceptual).
"""
