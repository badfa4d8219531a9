"""Hugin ``.pto`` projects, read and written without losing a line.

``tokens`` (splitting and number formatting), ``records`` (the ``p``, ``i``, ``v``, ``c`` and
``k`` lines as typed values) and ``project`` (a whole file: :class:`Project`).
"""
