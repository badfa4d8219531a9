"""Staged Levenberg-Marquardt on control points (``rigjax.optimise``).

``residuals`` (per-point errors and robust losses), ``point_jacobian`` and ``objective`` (the
stage's residuals and normal equations), ``schedule`` (``YPR,VBYPR`` and the parameter layout),
``problem`` (a project turned into padded arrays, once), ``lm`` (the compiled solve), ``staged``
(stages one after the other), ``prune`` (iterative removal of bad matches) and ``config`` (the
YAML of ``rigjax optimise``).
"""
