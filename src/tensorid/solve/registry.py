"""The fitting methods by name: the one place where a method's name is looked up.
Everything else asks the method object (its markers, see solvers.py). A method of
one's own joins with :func:`register` (or is passed to ``fit`` as an object);
tensorid/names.py spells the command line's --method choices out."""

from __future__ import annotations

from ..engine.modelling.checks import did_you_mean
from .baselines import FdBfgs, FdLsq
from .solvers import Auto, GaussNewton, Method, Newton, NewtonCG

REGISTRY: dict[str, type[Method]] = {
    cls.name: cls for cls in (Auto, Newton, NewtonCG, GaussNewton, FdBfgs, FdLsq)
}
# the built-ins (tensorid.METHODS); a method registered later joins REGISTRY
METHODS = tuple(REGISTRY)
LOCKSTEP = tuple(name for name, cls in REGISTRY.items() if cls.supports_batch)


def register(cls: type[Method]) -> type[Method]:
    """``cls`` chosen by its ``name`` (``fit(problem, method=name)``); a class
    decorator too."""
    REGISTRY[cls.name] = cls
    return cls


def resolve(method: str | Method) -> Method:
    """The method called ``method`` (a method object is returned as it is)."""
    if isinstance(method, Method):
        return method
    cls = REGISTRY.get(method) if isinstance(method, str) else None
    if cls is None:
        names = list(REGISTRY)
        hint = did_you_mean(method, names) if isinstance(method, str) else ""
        raise ValueError(f"unknown method {method!r}{hint}; choose one of {names}")
    return cls()


def exact_derivatives(name: str) -> bool:
    """Whether the method called ``name`` uses exact derivatives (not finite differences)."""
    return resolve(name).exact_derivatives


def listed(marker: str, last: str = "or") -> str:
    """The methods with ``marker`` set, for a message: "'auto', 'newton' or ..."."""
    names = [repr(n) for n, cls in REGISTRY.items() if getattr(cls, marker)]
    return ", ".join(names[:-1]) + f" {last} {names[-1]}" if len(names) > 1 else names[0]
