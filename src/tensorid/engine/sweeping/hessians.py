"""How a Problem's exact Hessian is computed: the Hessian paths, as objects.

A path is a :class:`HessianPath`: its ``name`` (``Problem(hessian=...)``,
``--hessian``, fit.json's ``hessian_path``), its markers (``supports(discretisation)``,
``supports_predictors``) and ``sweep``, the sweep that gives (J, ∇J, ∇²J, the
Gauss-Newton part) and the letters of its parts (see ``Problem._assemble``).
:class:`TransitionTensors` (the paper's, forward in time) and
:class:`SecondOrderAdjoints` (parallel in time, explicit schemes only,
engine/sweeping/adjoint.py) are the two; :class:`AutoHessian` chooses between them by the
measured cost model (:func:`tensorid.engine.adjoint.predicted_seconds`). A new path
is one class registered with :func:`register_hessian` (or passed as an object); the
checks ask its markers, never its name.
"""

from __future__ import annotations

import functools
from typing import ClassVar, TypeVar

from ..modelling.checks import from_registry
from .adjoint import adjoint_pays, predicted_seconds, supports, threads

# the paths by name: the one place a path's name is looked up (``get_hessian``);
# tensorid/names.py spells the command line's --hessian choices out
REGISTRY: dict[str, type[HessianPath]] = {}


class HessianPath:
    """A way to compute (J, ∇J, ∇²J, Gauss-Newton part) in one sweep.

    Markers:
        supports_predictors: the path differentiates any predictor (its field,
            predict and update), not only output error's model; where it does not,
            a predictor without the marker ``supports_adjoint`` is refused.
        takes_gaps: the path's sweep reads records whose samples carry a mask (a
            record with gaps or events, ``dosing.measured``).
        masks_one_record: the path takes a gap-free single record with its mask too
            (``Problem.masked``: the model-error check's halves then run the fit's
            programs); a new path opts in, so that its sweep's y stays as it was.
    """

    name: ClassVar[str] = ""
    supports_predictors: ClassVar[bool] = True
    takes_gaps: ClassVar[bool] = True
    masks_one_record: ClassVar[bool] = False
    needs: ClassVar[str] = "a scheme it can differentiate"  # (for a refusal)

    def supports(self, discretisation) -> bool:
        """Whether the path can differentiate this discretisation."""
        return True

    def refusal(self, discretisation) -> str:
        """The line that says why a discretisation is not supported, and the way out."""
        return (
            f"hessian={self.name!r} cannot differentiate scheme "
            f"{discretisation.scheme.name!r}: use hessian='tensors' or 'auto'"
        )

    def sweep(self, sweeps, batched: bool, threads_cap):
        """(the sweep giving J, ∇J, ∇²J and the Gauss-Newton part, its parts letters)."""
        raise NotImplementedError

    def made(self, sweeps, batched: bool, threads_cap):
        """``sweep``'s answer, made once per Sweeps, path and arguments (kept in
        ``sweeps.made``, which goes with them and is not pickled): a path that builds
        its function in ``sweep`` (a ``jax.jit`` of its own, as the recipe in
        docs/architecture.md) would otherwise be traced again at every call of a fit."""
        key = (type(self), batched, threads_cap)
        if key not in sweeps.made:
            sweeps.made[key] = self.sweep(sweeps, batched, threads_cap)
        return sweeps.made[key]

    def __eq__(self, other) -> bool:
        return type(self) is type(other)

    def __hash__(self) -> int:
        return hash(type(self))

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


_H = TypeVar("_H", bound=type[HessianPath])


def register_hessian(cls: _H) -> _H:
    """Class decorator: ``cls`` chosen by its ``name`` (``Problem(hessian=...)``)."""
    REGISTRY[cls.name] = cls
    return cls


def get_hessian(hessian) -> HessianPath:
    """The path called ``hessian`` (a HessianPath is returned as it is); one line
    for anything else."""
    return from_registry(hessian, REGISTRY, HessianPath, "hessian")


@register_hessian
class AutoHessian(HessianPath):
    """The faster of the tensors and the adjoint by the cost model (the adjoint where
    it is predicted MARGIN times faster and to save more than its longer compile over
    a fit's calls, and the scheme and the predictor allow it: adjoint.adjoint_pays; a
    filter's is the tensors'). Resolved by :func:`choose_hessian`, never swept."""

    name: ClassVar[str] = "auto"

    def choose(self, discretisation, N: int, K: int, samples, cap, adjoint: bool):
        if not adjoint or not supports(discretisation):
            return TransitionTensors()
        t = predicted_seconds(N, K, samples, threads(cap))
        return SecondOrderAdjoints() if adjoint_pays(t) else TransitionTensors()


@register_hessian
class TransitionTensors(HessianPath):
    """The paper's transition tensors, integrated forward with the states."""

    name: ClassVar[str] = "tensors"
    masks_one_record: ClassVar[bool] = True

    def sweep(self, sweeps, batched: bool, threads_cap):
        return (sweeps.second_order_both_batch if batched else sweeps.second_order_both), "JgPP"


@register_hessian
class SecondOrderAdjoints(HessianPath):
    """Second-order adjoints, parallel in time over stretches of the record
    (engine/sweeping/adjoint.py): explicit Runge-Kutta schemes and discrete-time models."""

    name: ClassVar[str] = "adjoint"
    supports_predictors: ClassVar[bool] = False
    takes_gaps: ClassVar[bool] = False
    needs: ClassVar[str] = "an explicit scheme"

    def supports(self, discretisation) -> bool:
        return supports(discretisation)

    def refusal(self, discretisation) -> str:
        return (
            f"hessian='adjoint' needs an explicit Runge-Kutta scheme or a discrete-time "
            f"model, not scheme {discretisation.scheme.name!r} (reverse-mode derivatives "
            "cannot go through its step control or stage solves): use hessian='tensors' "
            "or 'auto'"
        )

    def sweep(self, sweeps, batched: bool, threads_cap):
        adjoint = sweeps.adjoint_batch if batched else sweeps.adjoint
        return functools.partial(adjoint, threads_cap=threads_cap), "JgHH"


# the command line's order (tensorid/names.py); a path registered later joins REGISTRY
HESSIANS = ("auto", "tensors", "adjoint")


def choose_hessian(
    hessian, discretisation, N: int, K: int, samples, cap=None, adjoint: bool = True
) -> HessianPath:
    """The Hessian path a Problem uses: ``hessian`` (a name or a path) checked against
    the discretisation, and "auto" resolved (:class:`AutoHessian`), with at most
    ``cap`` threads; ``adjoint``: the predictor's marker ``supports_adjoint``."""
    path = get_hessian(hessian)
    if not path.supports(discretisation):
        raise ValueError(path.refusal(discretisation))
    if isinstance(path, AutoHessian):
        return path.choose(discretisation, N, K, samples, cap, adjoint)
    return path
