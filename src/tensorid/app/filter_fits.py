"""A filter fit's fit.json read back for `simulate` and `compare`: the filter's model
(its noise intensities among the parameters) and noise levels it can compute with;
and compare's status where such a filter's scores are not finite."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .files import ModelSpec


def filter_of(spec: ModelSpec, fitted: dict | None, record) -> tuple[ModelSpec, tuple | None]:
    """For a fit.json whose predictor corrects its state (a filter, predictor "ekf",
    or any registered predictor with the marker ``filters``): the spec with the
    predictor's model (a noise model's intensities among the parameters) and (loss,
    predictor) to predict with; otherwise ``spec`` and None (output error: the
    prediction is the simulation). A predictor name no registry knows is one line,
    never a silent simulation."""
    if fitted is None or fitted.get("predictor") is None:
        return spec, None
    from ..engine.sweeping.predictors import get_predictor, make_predictor

    kind = get_predictor(fitted["predictor"])  # (its markers answer, not its name)
    if not kind.filters:
        return spec, None
    q, r = _noise_terms(fitted) if kind.has_noise_model else (None, None)
    y = None if record.y is None else record.measured_with_gaps
    model, filt, _ = make_predictor(spec.model, kind, q, r, [y])
    return replace(spec, model=model), (filt.own_loss or _fitted_loss(fitted), filt)


def _fitted_loss(fitted: dict):
    """The loss a fit.json names (the squared loss where it names none)."""
    from ..engine.sweeping.losses import get_loss

    return get_loss(fitted.get("loss") or "squared")


# a noise level's log within these: σ² and the innovations' covariance stay finite
LOG_SIGMA_RANGE = 300.0


def _noise_terms(fitted: dict) -> tuple[dict, dict]:
    """A filter fit's noise intensities {state: σ_w}, {output: σ_e}: its params'
    log_sigma_w_<state>, log_sigma_e_<output> (what --params NAME=VALUE may change),
    else its noise_intensities; each one a filter can compute with."""
    params = fitted["params"]
    logs = {k: v for k, v in params.items() if k.startswith(("log_sigma_w_", "log_sigma_e_"))}
    if logs:
        # which terms the filter has (their values are these params, checked later)
        q = {k[12:]: 1.0 for k in logs if k[:12] == "log_sigma_w_"}
        return q, {k[12:]: 1.0 for k in logs if k[:12] == "log_sigma_e_"}
    noise = fitted.get("noise_intensities")
    if not isinstance(noise, dict) or not noise.get("process"):
        raise ValueError(
            f'it says "predictor": "{fitted["predictor"]}" but holds no noise terms (no '
            "log_sigma_w_<state> in its params, no noise_intensities): a filter cannot be "
            f"run from it; give the fit.json tensorid fit --predictor {fitted['predictor']} "
            "wrote"
        )
    q = {s: v["sigma"] for s, v in noise["process"].items()}
    r = {o: v["sigma"] for o, v in (noise.get("measurement") or {}).items()}
    return q, r


def noise_levels(params: dict, pairs: dict, path: str) -> None:
    """A filter's noise levels (log σ) ones it can compute with, named where they came
    from (``pairs``, the NAME=VALUE after the fit.json, or the fit.json at ``path``)."""
    for k, v in params.items():
        if k.startswith(("log_sigma_w_", "log_sigma_e_")) and not abs(v) <= LOG_SIGMA_RANGE:
            where = f"--params {k}={v:g}" if k in pairs else f"--params {path}: its {k} = {v:g}"
            raise ValueError(
                f"{where} is no noise level a filter can compute with (σ = e^{v:g} "
                f"{'overflows' if v > 0 else 'underflows'}); a fit gives |log σ| well below "
                f"{LOG_SIGMA_RANGE:g}: refit, or correct the file"
            )


NOT_SCORED = "scores_not_finite"  # compare.json's status: a finite simulation, no scores


def scores_finite(score) -> bool:
    """Whether the RMSE of every output measured at two samples or more is finite (a
    filter whose predictions are not finite leaves a finite simulation but no score;
    an output measured fewer than twice has none to give)."""
    counts = score.scored
    return all(np.isfinite(v["rmse"]) for o, v in score.metrics().items() if counts[o] > 1)
