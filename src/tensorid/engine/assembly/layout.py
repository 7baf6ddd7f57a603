"""θ, the vector of unknowns: its layout over experiments, names, start and checks.

θ = (free initial states of experiment 1, ..., of experiment E, free parameters),
free initial states in ``free_x0`` order and parameters in model order, in natural
units. :class:`ThetaLayout` is the part of :class:`tensorid.Problem` that knows it
(a Problem is a ThetaLayout); it reads ``model``, ``experiments``, ``free_x0``,
``free_params``, ``x0`` and ``p0``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..modelling.data import Experiment
    from ..modelling.model import Model


class ThetaLayout:
    """The θ layout of a Problem (see the module docstring)."""

    model: Model
    experiments: list[Experiment]
    free_x0: list[str]
    free_params: list[str]
    x0: np.ndarray
    p0: np.ndarray

    @property
    def theta_entries(self) -> list[tuple[str, int | None]]:
        """(name, experiment index or None for parameters) for each entry of θ."""
        out: list[tuple[str, int | None]] = []
        for e in range(len(self.experiments)):
            out += [(n, e) for n in self.free_x0]
        return out + [(n, None) for n in self.free_params]

    @property
    def theta_names(self) -> list[str]:
        """Names of the entries of θ: "state(t0)" (with "[experiment]" when there are
        several) for free initial states, then parameter names."""
        E = len(self.experiments)
        names = []
        for n, e in self.theta_entries:
            if e is None:
                names.append(n)
            else:
                label = self.experiments[e].name or str(e)
                names.append(f"{n}(t0)" if E == 1 else f"{n}(t0)[{label}]")
        return names

    @property
    def K(self) -> int:
        """Number of unknowns (entries of θ)."""
        return len(self.experiments) * len(self.free_x0) + len(self.free_params)

    @property
    def theta0(self) -> np.ndarray:
        """The start: free x0 entries then free parameters, natural units."""
        m = self.model
        xs = [
            self.x0[e, m.states.index(n)]
            for e in range(len(self.experiments))
            for n in self.free_x0
        ]
        ps = [self.p0[m.params.index(n)] for n in self.free_params]
        return np.array(xs + ps, dtype=float)

    def check_theta(self, theta) -> np.ndarray:
        """θ as a float array (K,); a clear error for a wrong length or non-finite
        entries."""
        try:
            theta = np.asarray(theta, dtype=float).reshape(-1)
        except (TypeError, ValueError):  # a dict, text: numpy's message named neither
            raise TypeError(
                f"theta must be an array of the {self.K} unknowns {self.theta_names} in "
                f"that order (the problem's theta_names), got {type(theta).__name__}; "
                "start values by name go to the Problem (p0=, x0=)"
            ) from None
        if theta.shape != (self.K,):
            raise ValueError(
                f"theta must have {self.K} entries {self.theta_names}, got {theta.size}"
            )
        bad = [n for n, v in zip(self.theta_names, theta, strict=True) if not np.isfinite(v)]
        if bad:
            raise ValueError(f"theta has non-finite values for {bad}; give finite numbers")
        return theta

    def _slices(self, e: int) -> np.ndarray:
        """Indices into θ of experiment e's local θ (its free x0, then free params)."""
        nx, E = len(self.free_x0), len(self.experiments)
        return np.concatenate([np.arange(e * nx, (e + 1) * nx), np.arange(E * nx, self.K)]).astype(
            int
        )

    def unpack(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(params (M,), x0 (E, N)) with θ written into the fixed values."""
        theta = self.check_theta(theta)
        m = self.model
        p = self.p0.copy()
        x0 = self.x0.copy()
        for k, (name, e) in enumerate(self.theta_entries):
            if e is None:
                p[m.params.index(name)] = theta[k]
            else:
                x0[e, m.states.index(name)] = theta[k]
        return p, x0
