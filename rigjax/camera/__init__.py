"""The PanoTools camera model of Hugin and PTGui, in JAX.

``lenses`` (the projections and the focal length from the hfov), ``distortion`` (the radial
polynomial ``a, b, c`` and its inverse), ``rotation`` (yaw, pitch, roll), ``model`` (a rig's
:class:`Camera` and image pixel <-> world ray), ``panorama`` (the equirectangular canvas) and
``trafo`` (image pixel <-> panorama pixel, Hugin's ``pano_trafo``).
"""
