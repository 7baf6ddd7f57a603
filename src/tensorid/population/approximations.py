"""How a population fit approximates each unit's marginal likelihood: a kind of thing,
one class each, with capability markers, chosen by name in the one registry below
(``tensorid.fit(problem, method=...)``, ``--method``). objective.py asks the chosen
class, never its name.

Both take −2 log of the Laplace approximation at the unit's η̂; they differ in M_i,
the curvature whose log determinant is added (objective.py):

- ``FOCEI``: M_i = Σ_h A_hᵀ diag(σ_h⁻²) A_h + Ω⁻¹ with A = ∂ŷ/∂η and σ² at η̂ (NONMEM's
  FOCE INTER): first-order output sensitivities in the objective, one order fewer
  than Laplace everywhere; the default, and what NONMEM and nlmixr2 report.
- ``Laplace``: M_i = ∇²_ηη ℓ_i(η̂_i), exact; also takes samples below their limit
  (Beal's M3), whose likelihood is not a Gaussian residual.
"""

from __future__ import annotations

from typing import ClassVar


class Approximation:
    """A population fit's approximation. Markers: ``exact_curvature`` (M_i is the
    exact ∇²_ηη ℓ_i, else its first-order part), ``censored`` (takes Beal's M3);
    ``gradient_order`` and ``hessian_order``: the highest derivative of ŷ that the
    outer gradient and Hessian of O_i take (M_i's order in ŷ, plus one for the
    gradient through η̂(ψ) and one more for the Hessian; units.taylor expands ŷ that
    far)."""

    name: ClassVar[str]
    exact_curvature: ClassVar[bool]
    censored: ClassVar[bool]
    gradient_order: ClassVar[int]
    hessian_order: ClassVar[int]


class FOCEI(Approximation):
    name, exact_curvature, censored = "focei", False, False
    gradient_order, hessian_order = 2, 3  # M_i of ∂ŷ/∂η (and ∇²ℓ for η̂'s derivative)


class Laplace(Approximation):
    name, exact_curvature, censored = "laplace", True, True
    gradient_order, hessian_order = 3, 4  # M_i = ∇²_ηη ℓ_i: of ∂²ŷ/∂η²


# the one place an approximation's name is looked up (names.FLEET_METHODS spells it
# for the command line, which tests/test_architecture.py keeps equal)
APPROXIMATIONS: dict[str, type[Approximation]] = {c.name: c for c in (FOCEI, Laplace)}
