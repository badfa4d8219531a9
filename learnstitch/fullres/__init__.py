"""Full-resolution stitching of any calibrated rig: the depth at a working size, every input resampled
at the output's size (:mod:`learnstitch.fullres.render`). ``rig`` reads a ``.pto`` and its images,
``sight`` tabulates each camera's lens through rigjax, ``depth`` estimates and upsamples the depth,
``config`` is the ``render:`` section of a config."""
