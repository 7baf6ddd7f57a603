"""Population (mixed-effects) estimation of a fleet: one model, many units, each
unit's parameters the typical values times exp(η), η ~ N(0, Ω) (Ω diagonal, its
standard deviations ω), the rest shared, and each output's residual error by its
error model (:mod:`.errors`: additive, proportional, combined, exponential).

The layers, lowest first: :mod:`.units` (the fleet's records padded to one shape, and
each unit's outputs with their derivatives from the transition tensors), :mod:`.objective`
(the marginal likelihood by FOCEI or Laplace, each unit's inner problem, the exact outer
gradient and Hessian through the inner optimum), :mod:`.estimate` (the outer
trust-region fit, standard errors, empirical Bayes estimates, shrinkage),
:mod:`.result` (``PopulationResult``) and :mod:`.diagnostics` (the per-observation
table: PRED, IPRED, IWRES, CWRES, NPDE).
"""

from __future__ import annotations

from .estimate import fit_population
from .result import PopulationResult

__all__ = ["PopulationResult", "fit_population"]
