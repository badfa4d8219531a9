"""A rig calibrated from its images alone (``rigjax.calibrate``).

``features`` (detection and matching), ``seam`` (matches in the overlap bands), ``ransac``
(rotations from bearings), ``initial`` (orientations in closed form), ``levy`` (Lévy-flight
starts), ``template`` (the rig templates of ``configs/rig``) and ``pipeline`` (all of it in order).
"""
