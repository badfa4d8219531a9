"""The stopping rules and backend of every Levenberg-Marquardt stage, and the status codes a stage
ends with. Kept apart from the solver (:mod:`rigjax.optimiser.lm`), so that configuring and
reporting a solve imports neither optimistix nor jaxopt: a process that loads its solves'
compiled programs (:mod:`rigjax.compiled`) never needs them.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import RigjaxError

BACKENDS = ("optimistix", "jaxopt")
STATUS = ("converged", "max_steps", "diverged", "nonfinite")


@dataclass(frozen=True)
class SolverOptions:
    """Stopping rules of every stage. A stage stops at the first rule that holds:

    * ``max_steps`` LM steps;
    * the transfer RMS (px) is at most ``rms_threshold``;
    * a step changes the cost, and the linear model predicts it to change, by at most ``ftol``
      times the cost (MINPACK's relative-reduction rule; it also ends a stage whose trial steps
      are all rejected for round-off at the optimum);
    * an accepted step moves the parameters by less than ``xtol`` times their norm.

    A stage whose parameters a later stage optimises again (``YPR`` before ``VBYPR``) only starts
    that stage: its ``ftol`` is ``preliminary_ftol`` where that is larger. With the lens off
    nominal its optimum is no better a start than a point near it, and a robust loss can make the
    last part of the way a crawl of dozens of steps (Hugin's optimiser, too, ends its first
    strategy as soon as progress slows).

    The rules are data of the compiled solve: new values do not recompile; a new ``backend`` does.
    """

    max_steps: int = 100
    xtol: float = 1e-10
    ftol: float = 1e-12
    preliminary_ftol: float = 1e-3
    rms_threshold: float = 0.0
    backend: str = "optimistix"

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise RigjaxError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        if self.max_steps < 1:
            raise RigjaxError(f"max_steps must be at least 1, got {self.max_steps}")
        for name in ("xtol", "ftol", "preliminary_ftol", "rms_threshold"):
            if not getattr(self, name) >= 0.0:
                raise RigjaxError(f"{name} must be a number >= 0, got {getattr(self, name)!r}")
