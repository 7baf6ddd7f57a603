"""Data sensitivity: how much each estimate moves per unit change of each measured
sample, to find the samples that drive an estimate (outliers, saturation, a
transient that alone identifies a parameter).

At an optimum ∇J(θ̂, y) = 0. Differentiating with respect to a sample y_k, with
J = Σ w (y − ŷ)²,

    dθ̂/dy_k = −H⁻¹ ∂²J/∂θ∂y_k = 2 w_k H⁻¹ ∂ŷ_k/∂θ,

with H the exact Hessian at θ̂ (priors included) and ∂ŷ_k/∂θ the output
sensitivities, exact for the discretised model. Multiplied by the residual standard
deviation it reads as "how far θ̂_i moves when sample k moves by one noise level".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .summary import Table, Tabular
from .uncertainty import jacobi_scale


@dataclass(repr=False)
class DataSensitivity(Tabular):
    """dθ̂/dy for every sample of every record.

    values : one array per experiment, shape (P, S, K): the change of each estimate
        per unit change of each sample of each output.
    names : the unknowns (θ layout); sigma : the residual standard deviation, by which
        ``scaled`` multiplies (a one-noise-level change of a sample).
    residuals : one (P, S) array per experiment, y − ŷ at the estimate; ``pull``
        multiplies by them: how far each sample has pulled each estimate (to first
        order, the change if the sample were replaced by the model's prediction),
        which is what points at outliers.
    """

    names: list[str]
    values: list[np.ndarray]
    sigma: float
    times: list[np.ndarray]
    outputs: list[str]
    records: list[str]
    residuals: list[np.ndarray]
    weights: np.ndarray
    # per experiment, (P, S): which samples hold a measurement (None: all); a gap or a
    # row holding only a dose has dθ̂/dy = 0 and no residual, and is not counted
    seen: list[np.ndarray] | None = None

    def scaled(self, name: str) -> list[np.ndarray]:
        """|dθ̂_name/dy|·σ_s per experiment, (P, S): σ_s = σ/√w_s is output s's noise
        level (σ that of a unit-weight residual)."""
        i = self._index(name)
        level = self.sigma / np.sqrt(np.where(self.weights > 0, self.weights, np.inf))
        return [np.abs(v[:, :, i]) * level[None, :] for v in self.values]

    def _index(self, name: str) -> int:
        if name not in self.names:
            raise ValueError(f"unknown name {name!r}; the unknowns are {self.names}")
        return self.names.index(name)

    def pull(self, name: str) -> list[np.ndarray]:
        """dθ̂_name/dy·(y − ŷ) per experiment, (P, S)."""
        i = self._index(name)
        return [v[:, :, i] * r for v, r in zip(self.values, self.residuals, strict=True)]

    def most_influential(
        self, name: str, n: int = 5, by: str = "pull"
    ) -> list[tuple[str, int, str, float]]:
        """The n samples that matter most to θ̂_name: (record, sample, output, value),
        ``by`` "pull" (how far each has pulled the estimate: outliers) or "scaled"
        (how far one noise level would move it: leverage)."""
        rows = []
        arrays = self.pull(name) if by == "pull" else self.scaled(name)
        seen: list = list(self.seen) if self.seen else [None] * len(arrays)
        for e, a in enumerate(np.abs(x) for x in arrays):
            if seen[e] is not None:  # a sample not measured is none of them
                a = np.where(seen[e], a, -1.0)
                n_e = min(n, int(seen[e].sum()))
            else:
                n_e = n
            for k, s in zip(
                *np.unravel_index(np.argsort(a, axis=None)[::-1][:n_e], a.shape), strict=True
            ):
                rows.append((self.records[e], int(k), self.outputs[s], float(a[k, s])))
        return sorted(rows, key=lambda r: -r[3])[:n]

    def blocks(self) -> list:
        """Per unknown, the sample that has pulled its estimate furthest (outliers) and
        the one where a change of one noise level would move it most (leverage)."""
        samples = (
            sum(v.shape[0] for v in self.values)
            if self.seen is None
            else sum(int(m.any(axis=1).sum()) for m in self.seen)
        )
        head = (
            f"data sensitivity dθ̂/dy: {len(self.names)} unknowns, {samples} samples of "
            f"{', '.join(self.outputs)} in {len(self.records)} record(s), σ {self.sigma:.4g}"
        )
        header = ["unknown", "pulled most by", "pull", "most leverage at", "per σ"]
        rows = []
        for name in self.names:
            (r1, k1, o1, v1), (r2, k2, o2, v2) = (
                self.most_influential(name, 1, by)[0] for by in ("pull", "scaled")
            )
            rows.append([name, f"{r1}, {o1}[{k1}]", f"{v1:.3g}", f"{r2}, {o2}[{k2}]", f"{v2:.3g}"])
        return [head, Table(None, header, rows)]

    def __repr__(self) -> str:
        shapes = [v.shape for v in self.values]
        return f"DataSensitivity(names={self.names}, values (P, S, K) {shapes})"

    def figure(self, names=None):
        """One panel per unknown: |dθ̂/dy|·σ against time, per record and output."""
        from .figures import new_figure

        names = list(self.names if names is None else names)
        for name in names:
            self._index(name)  # an unknown name: one line before any drawing
        fig = new_figure(figsize=(9, 1.8 + 1.6 * len(names)))
        axes = np.atleast_1d(fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0])
        for ax, name in zip(axes, names, strict=True):
            for e, a in enumerate(self.scaled(name)):
                for s, out in enumerate(self.outputs):
                    label = f"{self.records[e]}, {out}" if ax is axes[0] else None
                    ax.plot(self.times[e], a[:, s], lw=0.8, label=label)
            ax.set_ylabel(f"{name}\nper σ", fontsize=8)
            ax.grid(alpha=0.3)
        axes[0].set_title(
            "change of each estimate when one sample moves by one noise level", fontsize=9
        )
        axes[0].legend(fontsize=7)
        axes[-1].set_xlabel("t [s]")
        fig.tight_layout()
        return fig


def data_sensitivity(res) -> DataSensitivity:
    """dθ̂/dy at the estimate of ``res`` (a :class:`FitResult` with error bars)."""
    if not res.has_uncertainty:
        raise ValueError(
            f"data sensitivity needs a fit with a finite optimum; it ended as {res.status}"
        )
    problem = res.problem
    if problem.loss.likelihood:
        raise ValueError(
            "data sensitivity is for output error (the squared loss); this fit's predictor "
            "is a filter (ekf), whose estimate depends on the data through it: fit with "
            "predictor='simulation' for it"
        )
    if not problem.loss.squared:  # dθ̂/dy below is that of Σ w r²
        raise ValueError(
            f"data sensitivity assumes the squared loss; this fit's is {problem.loss.name} "
            "(whose point is that a sample's pull is capped): fit with loss='squared' for it"
        )
    # the inverse in Jacobi-scaled (unit-free) form: in natural units the Hessian's
    # condition number can reach 1e18, past what a pseudo-inverse resolves
    sc = jacobi_scale(res.hess)
    Hs = 0.5 * (res.hess + res.hess.T) * np.outer(sc, sc)
    Hinv = np.linalg.pinv(Hs, rcond=1e-12, hermitian=True) * np.outer(sc, sc)
    w, exps = np.asarray(problem.weights), problem.experiments
    seen = [e.seen for e in exps]  # (where not measured: 0, whatever ∂ŷ/∂θ there)
    values = [
        2.0 * (w[:, None] * np.where(m[..., None], dy, 0.0)) @ Hinv.T  # (P, S, K)
        for dy, m in zip(problem.output_sensitivities(res.theta), seen, strict=True)
    ]
    return DataSensitivity(
        names=problem.theta_names,
        values=values,
        sigma=float(np.sqrt(res.uncertainty().sigma2)),
        times=[e.t for e in problem.experiments],
        outputs=list(problem.model.outputs),
        records=[e.name or str(i) for i, e in enumerate(problem.experiments)],
        weights=np.asarray(problem.weights, dtype=float),
        residuals=[
            np.where(m, e.measured - s.y, 0.0)
            for e, s, m in zip(exps, res.simulate(), seen, strict=True)
        ],
        seen=seen,
    )
