"""Equirectangular panoramas from a project's images.

``images`` (reading and writing images and video frames), ``remap`` (the panorama's sampling
maps), ``blend`` (feather and multi-band blending: ``rigjax.render``) and ``job`` (``rigjax render``
as a function).
"""
