"""Full-resolution stitching of any calibrated rig: the depth at a working size, every input resampled
at the output's size. ``stitcher`` prepares a rig once and stitches its frames
(:class:`~learnstitch.fullres.stitcher.Stitcher`, its depth sources); ``rig`` reads a ``.pto`` and its
images, ``sight`` tabulates each camera's lens through rigjax, ``depth`` estimates and upsamples the
depth, ``render`` renders one frame, ``config`` is the ``render:`` section of a config."""
