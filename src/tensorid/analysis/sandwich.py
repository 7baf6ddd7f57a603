"""The sandwich covariance: error bars that do not assume white Gaussian residuals.

At an optimum θ̂ of J = Σ_h ℓ_h + priors, θ̂ − θ ≈ −H⁻¹ ∇J, and ∇J's data part is the
sum of the per-sample scores s_h = D_hᵀ ℓ_ŷ,h (D_h = ∂ŷ_h/∂θ, ℓ_ŷ the loss's output
gradient, see engine/sweeping/losses.py). So

    cov(θ̂) = H⁻¹ B H⁻¹,      B = var(Σ_h s_h)

with H the exact Hessian. For the squared loss and white noise of variance σ²,
B = 2σ² H_GN and this is the textbook 2σ² H⁻¹. Two estimates of B:

* independent samples (``lags=0``): B = Σ_h s_h s_hᵀ. What a robust loss's error bars
  need (its J is not a sum of Gaussian log-likelihoods, so σ² J-scaling does not
  apply): Huber's M-estimator covariance, in the exact-Hessian form.
* coloured residuals (``lags="auto"``): Newey-West's HAC estimate
  B = Γ₀ + Σ_{l=1}^{L} (1 − l/(L+1)) (Γ_l + Γ_lᵀ),  Γ_l = Σ_h s_h s_{h−l}ᵀ,
  per experiment, with the bandwidth L from Andrews' (1991) AR(1) plug-in rule for
  the Bartlett kernel, L = 1.1447 (α n)^{1/3}, α fitted to the scores (each
  component normalised to unit variance, so that units do not weigh), after
  Andrews and Monahan's (1992) VAR(1) prewhitening: s_h = A s_{h−1} + e_h, B from
  the e_h, recoloured by (I − A)⁻¹. Residuals that are correlated over many samples
  (a model error, a disturbance) widen the bars where the white formula would make
  them narrower the longer the record. Measured coverage in docs/robust.md.

Both are multiplied by n / (n − K) (n samples, K unknowns), the usual small-sample
correction.
"""

from __future__ import annotations

import numpy as np

from ..engine.compiling.compiled import on_device
from ..engine.sweeping.losses import robust_sd
from .residuals import skipped_samples


def scores(problem, theta) -> list[np.ndarray]:
    """(P, K) per experiment: each sample's share s_h of ∇J (the priors aside), exact
    for the discretised model, from the fit's own first-order sweep (the terms of its
    ∇J, so they sum to it to rounding): for output error s_h = D_hᵀ ℓ_ŷ,h; for a filter
    (a likelihood) the shares of −2 log L through its updates, on the samples the
    likelihood uses (the one it leaves out, skipped_samples, is left out here too)."""
    theta = problem.check_theta(theta)
    sw, w = problem.sweeps, on_device(problem.loss_weights)
    first = skipped_samples(problem)
    out = []
    for e, (t, u, y) in enumerate(problem.arrays):
        idx = problem._slices(e)
        x0, p = on_device(problem.x0[e]), on_device(problem.p0)
        s = np.asarray(sw.scores(on_device(theta[idx]), x0, p, t, u, y, w))
        full = np.zeros((s.shape[0], problem.K))
        full[:, idx] = s
        out.append(full[first:])
    return out


def bandwidth(parts: list[np.ndarray]) -> int:
    """Andrews' AR(1) plug-in bandwidth for the Bartlett kernel, from the scores of
    every experiment together; at most the shortest experiment's length − 1."""
    n = sum(s.shape[0] for s in parts)
    sd = np.sqrt(np.mean(np.concatenate(parts) ** 2, axis=0))
    keep = sd > 0
    if not keep.any() or min(s.shape[0] for s in parts) < 3:
        return 0
    lag = sum((s[1:, keep] * s[:-1, keep]).sum(0) for s in parts)
    var = sum((s[:-1, keep] ** 2).sum(0) for s in parts)
    rho = np.clip(lag / var, -0.99, 0.99)
    sig2 = 1 - rho**2  # the AR(1) innovation variance of a unit-variance component
    num = float(np.sum(4 * rho**2 * sig2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)))
    den = float(np.sum(sig2**2 / (1 - rho) ** 4))
    L = int(1.1447 * (num / den * n) ** (1 / 3)) if den > 0 else 0
    return min(L, min(s.shape[0] for s in parts) - 1)


def _prewhiten(parts: list[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
    """Andrews and Monahan's VAR(1) prewhitening: s_h = A s_{h−1} + e_h fitted to every
    record's scores together, returning (the residuals e per record, (I − A)⁻¹). A's
    singular values are capped at 0.97 (theirs): near 1, (I − A)⁻¹ would explode."""
    sd = np.sqrt(np.mean(np.concatenate(parts) ** 2, axis=0))
    sd = np.where(sd > 0, sd, 1.0)  # unit-free: each component to unit variance
    z = [s / sd for s in parts]
    lag = sum(a[1:].T @ a[:-1] for a in z)
    var = sum(a[:-1].T @ a[:-1] for a in z)
    A = lag @ np.linalg.pinv(var, hermitian=True)
    U, sv, Vt = np.linalg.svd(A)
    A = (U * np.minimum(sv, 0.97)) @ Vt
    e = [np.vstack([a[:1], a[1:] - a[:-1] @ A.T]) for a in z]
    back = np.linalg.inv(np.eye(A.shape[0]) - A)
    return [x * sd for x in e], (sd[:, None] * back) / sd[None, :]


def score_covariance(problem, theta, lags="auto") -> tuple[np.ndarray, int]:
    """(B (K, K), L): the scores' covariance, independent samples for ``lags`` 0,
    Newey-West with L lags for an integer, and for "auto" prewhitened (VAR(1), see
    _prewhiten) with Andrews' bandwidth on what the VAR leaves; on the samples that
    hold a measurement (as the residual tests: a gap's or an event's row has no
    score, and counted it would dilute the lags and n)."""
    first = skipped_samples(problem)
    parts = []
    for e, s in zip(problem.experiments, scores(problem, theta), strict=True):
        seen = np.zeros(s.shape[0] + first, dtype=bool)  # (a moving event's nodes last)
        seen[: e.P] = e.seen_rows
        parts.append(s[seen[first:]])
    K = problem.K
    back = np.eye(K)
    if lags == "auto" and min(s.shape[0] for s in parts) > 2 * K + 2:
        parts, back = _prewhiten(parts)
    L = bandwidth(parts) if lags == "auto" else int(lags)
    B = np.zeros((K, K))
    for s in parts:
        B += s.T @ s
        for lag in range(1, min(L, s.shape[0] - 1) + 1):
            G = s[lag:].T @ s[:-lag]
            B += (1.0 - lag / (L + 1.0)) * (G + G.T)
    counted = problem.weights > 0  # the measured values, not rows × outputs
    n = sum(int(e.seen[first:][:, counted].sum()) for e in problem.experiments)
    return back @ B @ back.T * n / max(n - K, 1), L


# Why a robust loss's scale can fall below what the data resolve. In the sandwich
# H⁻¹ B H⁻¹ the scores carry the scale (Huber's ℓ_ŷ = −2c sign(e) beyond it, so B ∝ c²)
# and so must the Hessian: its data part Σ_h D_hᵀ w ρ''(z_h) D_h counts the residuals
# inside the scale (ρ'' = 2 there, 0 beyond), a uniform-kernel estimate of
# 2 P(|e| ≤ c) ≈ 4 c f(0) (f the residuals' density) — ∝ c, and c² / c² cancels:
# the least-absolute-deviation limit, whose covariance is (4 f(0)²)⁻¹ (DᵀD)⁻¹. But the
# count is only ∝ c while the band holds many residuals. Below the residuals' own
# spacing the fit sits at an LAD vertex with about K residuals at zero, the count
# stops falling with c, H stays O(1) while B ∝ c², and the error bars shrink ∝ c
# (measured: 30× too narrow at c = 1e-4 σ, with 5 of 1,000 residuals inside).
# So, below the kernel bandwidth h the data resolve (Silverman's 0.9 σ̂ n^(-1/5)), a
# Huber fit's bread uses P(|e| ≤ c) ≈ (c / h) · share(|e| ≤ h) instead (the same
# density at 0, with enough residuals to count); Cauchy's and Student-t's curvature
# integrates to 0 over z (they redescend), so theirs has no such limit: no error bars.


def unresolved_scale(problem, theta) -> tuple[np.ndarray | None, str | None]:
    """For a robust loss whose scale is below the residuals' resolution on some output
    (see above): (the Hessian to use as the sandwich's bread, or None, and the line
    saying so); (None, None) where every scale is resolved (the exact Hessian is the
    bread)."""
    if not problem.loss.robust:
        return None, None
    w, c = np.asarray(problem.loss_weights[0]), np.asarray(problem.loss_weights[1])
    sims, exps = problem.simulate(theta), problem.experiments
    e = np.concatenate(
        [np.sqrt(w) * (x.y - s.y) for x, s in zip(exps, sims, strict=True)]
    )  # (rows, S) weighted residuals, in the scale's units
    seen = np.concatenate([x.seen for x in exps])  # (not a gap, nor a dose's row)
    cols = [e[seen[:, j], j] for j in range(e.shape[1])]  # each output's residuals
    n = np.array([a.size for a in cols])
    sd = np.array([robust_sd(a) if a.size else np.inf for a in cols])  # (measured nowhere)
    h = 0.9 * sd * np.maximum(n, 1) ** (-0.2)
    counts = (w > 0) & (n > 0)
    low = counts & (c < h)
    if not low.any():
        return None, None
    inside = np.array([(np.abs(a) <= cj).sum() for a, cj in zip(cols, c, strict=True)])
    names = [o for o, b in zip(problem.model.outputs, low, strict=True) if b]
    scale = problem.loss_scale
    which = ", ".join(
        f"{o} c = {scale[o]:.3g} (bandwidth {h[i] / np.sqrt(w[i]):.3g}, {inside[i]} of {n[i]} "
        "residuals inside)"
        for i, o in enumerate(problem.model.outputs)
        if o in names
    )
    head = f"the {problem.loss.name} scale is below what these residuals resolve: {which}"
    if not problem.loss.quadratic_inside:  # (Huber: ρ'' is 2 inside the scale, 0 beyond)
        return None, (
            f"not available: {head}; a {problem.loss.name} loss with so small a scale has "
            "no error bars to give (its curvature inside the scale no longer measures "
            "the data's information); use a larger loss scale, or drop loss_scale to "
            "have it estimated"
        )
    near = [np.mean(np.abs(a) <= b) if a.size else 0.0 for a, b in zip(cols, h, strict=True)]
    near_c = [np.mean(np.abs(a) <= b) if a.size else 0.0 for a, b in zip(cols, c, strict=True)]
    share = np.where(low, (c / np.where(h > 0, h, 1.0)) * near, near_c)
    gamma = np.where(counts, 2.0 * w * share, 0.0)  # E[ℓ_ŷŷ] per output
    H = np.diag(problem.prior_curvature).astype(float)
    for D, x in zip(problem.output_sensitivities(theta), exps, strict=True):
        D = np.where(x.seen[..., None], D, 0.0)  # a sample not measured brings nothing
        H += np.einsum("hsk,s,hsj->kj", D, gamma, D)
    return H, (
        f"{head}: the fit is least-absolute deviations there, and its error bars take the "
        "residuals' density at zero from that bandwidth (the exact Hessian counts only "
        "the residuals inside the scale: too few, and the bars would shrink with it)"
    )
