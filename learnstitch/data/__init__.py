"""Synthetic training data with true parallax.

``textures`` and ``scene`` (procedural street scenes, ray cast), ``rig`` (the three-fisheye rig
and its unwarp grids, through rigjax's camera model), ``sample`` (one triplet and its
ground-truth panorama), ``store`` (samples on disk, written atomically), ``generate`` (filling a
folder in parallel, resumable) and ``datasets`` (the torch datasets).
"""
