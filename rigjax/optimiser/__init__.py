"""Staged Levenberg-Marquardt on control points (``rigjax.optimise``).

``residuals`` (per-point errors and robust losses), ``point_jacobian`` and ``objective`` (the
stage's residuals and normal equations), ``schedule`` (``YPR,VBYPR`` and the parameter layout),
``problem`` (a project turned into padded arrays, once), ``lm`` (the compiled solve), ``staged``
(stages one after the other), ``bundle`` (cameras with centres and the control points as scene
points, the ``reprojection`` objective), ``prune`` (iterative removal of bad matches), ``config``
(the settings of one optimisation, ``OptimiseConfig``: the YAML of ``rigjax optimise``) and
``result`` (``OptimiseResult``, what every objective's solve returns).
"""
