"""A rig calibrated from its images alone (``rigjax.calibrate``).

``features`` (detection and matching), ``seam`` (matches in the overlap bands), ``ransac``
(rotations from bearings), ``initial`` (orientations in closed form), ``levy`` (Lévy-flight
starts), ``template`` (the rig templates of ``configs/rig``), ``stages`` (matches to a calibrated rig,
a function per stage), ``pipeline`` (all of it in order) and ``job`` (``rigjax calibrate`` as a function).
"""
