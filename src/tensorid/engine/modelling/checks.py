"""The checks of a Problem's input: every mistake in the data, start values, weights and
bounds is one clear line before anything compiles. Each function takes the Problem
under construction (what it has set so far) and returns the checked value."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from .data import Experiment
from .initial import evaluate, has_expressions

# MATLAB's first-order hold is linear interpolation, its 'bl' band-limited; a Kalman
# filter is the EKF here
_ALIASES = {"foh": "linear", "bl": "bandlimited", "spline": "cubic", "kalman": "ekf"}


def nearest(value, choices: Sequence[str]) -> str | None:
    """The choice a misspelt ``value`` most likely meant ('sdrik3': 'sdirk3', 'RK4':
    'rk4', MATLAB's 'foh': 'linear'), or None."""
    import difflib

    text = str(value).lower()
    if text in choices or _ALIASES.get(text) in choices:
        return text if text in choices else _ALIASES[text]
    close = difflib.get_close_matches(text, list(choices), n=1, cutoff=0.6)
    return close[0] if close else None


def did_you_mean(value, choices: Sequence[str]) -> str:
    """ " (did you mean 'sdirk3'?)" for the choice nearest to a misspelt ``value``, or ""."""
    close = nearest(value, choices)
    return f" (did you mean {close!r}?)" if close else ""


def from_registry(value, registry: dict, base: type, what: str):
    """``value`` itself where it is a ``base`` object, else the class ``registry``
    holds under that name, made; one line naming the choices for anything else (the
    one lookup of the loss, predictor and Hessian-path registries)."""
    if isinstance(value, base):
        return value
    cls = registry.get(value) if isinstance(value, str) else None
    if cls is None:
        names = tuple(registry)
        close = did_you_mean(value, names)
        raise ValueError(f"{what} must be one of {names}, got {value!r}{close}")
    return cls()


def name_list(what: str, names, known: Sequence[str], kind: str) -> list[str]:
    if names is None:
        return []
    if isinstance(names, str):
        names = [names]
    names = list(names)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(
            f"{what} names unknown {kind} {unknown}; the model's {kind} are {list(known)}"
        )
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{what} repeats {dup}")
    return names


def check_data(problem, data) -> list[Experiment]:
    if not isinstance(data, Experiment | list | tuple):
        raise TypeError(
            f"data must be a tensorid.Experiment or a list of them, got "
            f"{type(data).__name__}; build one with ti.Experiment(t, u, y) or read "
            "files with ti.load_data(path, model)"
        )
    exps = [data] if isinstance(data, Experiment) else list(data)
    if not exps:
        raise ValueError("data is empty: pass an Experiment or a list of them")
    m = problem.model
    for i, e in enumerate(exps):
        if not isinstance(e, Experiment):
            raise TypeError(
                f"data: experiment {i} is a {type(e).__name__}, not a tensorid.Experiment"
            )
        where = f"experiment {i}" + (f" ({e.name})" if e.name else "")
        if e.y is None:
            raise ValueError(f"{where} has no measured outputs y; a fit needs them")
        if e.u.shape[1] != m.U:
            raise ValueError(
                f"{where} has {e.u.shape[1]} input column(s) but the model "
                f"has {m.U} inputs {list(m.inputs)}"
            )
        if m.discrete:
            uniform_steps(e, where)
        if e.y.shape[1] != m.S:
            raise ValueError(
                f"{where} has {e.y.shape[1]} output column(s) but the model "
                f"has {m.S} outputs {list(m.outputs)}"
            )
    if m.discrete:
        for i, e in enumerate(exps[1:], 1):
            same_step(m, e, step(exps[0]), f"experiment {i}" + (f" ({e.name})" if e.name else ""))
    return exps


def step(e: Experiment) -> float:
    """A record's sampling interval (the mean of its steps)."""
    return float((e.t[-1] - e.t[0]) / (e.P - 1))


def uniform_steps(e: Experiment, where: str) -> None:
    """A discrete-time model's record sampled at one rate (it steps once per sample)."""
    if e.P > 2:
        dt = np.diff(e.t)
        if np.abs(dt - dt.mean()).max() > 1e-6 * abs(dt.mean()):
            raise ValueError(
                f"{where}: a discrete-time model steps once per sample, but the "
                f"sample times are not uniform (steps {dt.min():.6g} to {dt.max():.6g} s); "
                "resample the record to one rate, or take the samples as uniform with the "
                "sampling time (--ts on the command line, ts= in load_data)"
            )


def same_step(model, e: Experiment, fitted: float | None, where: str) -> None:
    """A discrete-time model steps once per sample: a record sampled at another rate
    than the model was fitted at is another model (it ran, silently)."""
    if not model.discrete or fitted is None or e.P < 2:
        return
    uniform_steps(e, where)  # uneven stamps first: their mean step is no rate at all
    if abs(step(e) - fitted) > 1e-6 * fitted:
        raise ValueError(
            f"{where} is sampled every {step(e):.6g} s, the discrete-time model's records "
            f"every {fitted:.6g} s: its step is one sample, so it is another model at "
            "another rate; resample the record to the model's rate"
        )


def check_x0(problem, x0) -> np.ndarray:
    m, E = problem.model, len(problem.experiments)
    if x0 is None:
        return np.zeros((E, m.N))
    if has_expressions(x0):  # {"depot": "Dose * Wt"}: per record, at its first sample
        arr, problem.x0_uses = evaluate(m, problem.experiments, x0, problem.p0)
        problem.x0_expressions = dict(x0)  # a fleet's fit may move them with θ
        return arr
    if isinstance(x0, Mapping):
        return np.tile(m.states_array(x0), (E, 1))
    if isinstance(x0, Sequence) and x0 and isinstance(x0[0], Mapping):
        if len(x0) != E:
            raise ValueError(f"x0 has {len(x0)} dicts but there are {E} experiments")
        return np.stack([m.states_array(d, f"x0[{i}]") for i, d in enumerate(x0)])
    arr = np.asarray(x0, dtype=float)
    if arr.ndim == 1:
        return np.tile(m.states_array(arr), (E, 1))
    if arr.shape != (E, m.N):
        raise ValueError(
            f"x0 must have shape ({m.N},) or ({E}, {m.N}) for "
            f"{E} experiment(s) and states {list(m.states)}, got {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise ValueError("x0 contains non-finite values")
    return arr


def check_weights(problem, weights) -> np.ndarray:
    m = problem.model
    scale = output_scales(problem)
    never = [o for o, v in zip(m.outputs, scale, strict=True) if np.isnan(v)]
    if never:
        warnings.warn(
            f"output(s) {never} are measured at no sample of any record: they add nothing "
            "to the fit; check the data's columns (or DVID), or leave them out of the model",
            UserWarning,
            stacklevel=3,
        )
    if weights is None:
        known = scale[~np.isnan(scale)]  # the scales of the outputs measured
        if known.size > 1 and known.min() > 0 and known.max() / known.min() > 1e3:
            sizes = ", ".join(f"{o} ~ {v:.1e}" for o, v in zip(m.outputs, scale, strict=True)
                              if not np.isnan(v))  # fmt: skip
            scale = known
            warnings.warn(
                f"the outputs differ in scale by {scale.max() / scale.min():.0e} ({sizes}) "
                "and no weights were given: the fit will all but ignore the small ones; "
                "pass weights='auto' (1/variance of each output) or weights={output: w}",
                UserWarning,
                stacklevel=3,
            )
        return np.ones(m.S)
    if isinstance(weights, str):
        if weights != "auto":
            raise ValueError(f"weights must be 'auto', a dict or an array, got {weights!r}")
        flat = [o for o, v in zip(m.outputs, scale, strict=True) if v == 0]
        if flat:
            raise ValueError(
                f"weights='auto' needs outputs that vary; {flat} are constant in the data: "
                "give weights={output: w} instead"
            )
        return np.where(np.isnan(scale), 0.0, 1.0 / scale**2)  # never measured: weighs 0
    if isinstance(weights, Mapping):
        w = name_list("weights", list(weights), m.outputs, "outputs")
        out = np.ones(m.S)
        for n in w:
            out[m.outputs.index(n)] = float(weights[n])
    else:
        out = np.asarray(weights, dtype=float).reshape(-1)
        if out.shape != (m.S,):
            raise ValueError(f"weights must have one value per output {list(m.outputs)}")
    if not np.isfinite(out).all() or (out < 0).any():
        raise ValueError("weights must be finite and non-negative")
    return out


def output_scales(problem) -> np.ndarray:
    """The standard deviation of each measured output, all experiments together, over
    its own measured samples (outputs may be sampled at different times); NaN for an
    output measured nowhere, inf where the values overflow it."""
    y = np.concatenate([e.y if e.observed is None else e.measured_with_gaps
                        for e in problem.experiments])  # fmt: skip
    never = np.isnan(y).all(axis=0) if y.size else np.zeros(y.shape[1], bool)
    with np.errstate(over="ignore", invalid="ignore"):
        sd = (np.std(y, axis=0) if not np.isnan(y).any()
              else np.array([np.std(a[~np.isnan(a)]) if (~np.isnan(a)).any() else np.nan
                             for a in y.T]))  # fmt: skip
        return np.where(np.isnan(sd) & ~never, np.inf, sd)


def check_bounds(problem, bounds: Mapping) -> tuple[np.ndarray, np.ndarray]:
    m = problem.model
    name_list("bounds", list(bounds), list(m.params) + list(m.states), "params or states")
    for name in bounds:
        if name in problem.fixed:
            raise ValueError(f"bounds given for {name!r}, which is fixed; drop one of them")
        if name in m.states and name not in problem.free_x0:
            raise ValueError(
                f"bounds given for the initial state {name!r}, which is not "
                "in free_x0; add it to free_x0 or drop the bound"
            )
    lo = np.full(problem.K, -np.inf)
    hi = np.full(problem.K, np.inf)
    names = problem.theta_entries
    for k, (name, _) in enumerate(names):
        if name in bounds:
            try:
                a, b = bounds[name]
            except (TypeError, ValueError):
                raise ValueError(
                    f"bounds[{name!r}] must be a pair (lo, hi), got {bounds[name]!r}"
                ) from None
            a = -np.inf if a is None else float(a)
            b = np.inf if b is None else float(b)
            if np.isnan(a) or np.isnan(b):
                raise ValueError(
                    f"bounds[{name!r}] = ({a}, {b}) holds NaN; give numbers, or None "
                    "(or -inf/inf) for no bound on that side"
                )
            if a > b:
                raise ValueError(f"bounds[{name!r}] = ({a}, {b}) has lo > hi; swap them")
            lo[k], hi[k] = a, b
    theta0 = problem.theta0
    out = (theta0 < lo) | (theta0 > hi)
    if out.any():
        k = int(np.argmax(out))
        what = "p0" if names[k][0] in m.params else "x0"
        raise ValueError(
            f"{what}[{names[k][0]!r}] = {theta0[k]:g} is outside its bounds "
            f"({lo[k]:g}, {hi[k]:g}); move the start inside or widen the "
            "bounds"
        )
    return lo, hi


def check_p0(problem, p0) -> np.ndarray:
    """The parameters' start values (M,), required."""
    if p0 is None:
        raise ValueError(
            f"p0 is required: give a start value for every parameter "
            f"{list(problem.model.params)} (dict or array)"
        )
    return problem.model.params_array(p0, "p0")


def check_threads(threads) -> int | None:
    """A cap on the adjoint's threads: None or a whole number >= 1."""
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, int) or threads < 1
    ):
        raise ValueError(f"threads must be a whole number >= 1 or None, got {threads!r}")
    return threads


def check_filter_options(predictor, **options) -> None:
    """One line, before any work, for an option that ``predictor`` (a Predictor)
    cannot serve, as its markers say: a filter (predictor="ekf") estimates its own
    noise with its own loss (``takes_loss``), corrects the state at every sample
    (``supports_segments``) and is differentiated by the tensors only
    (``supports_adjoint``). ``loss`` and ``hessian`` come as their registries'
    objects where their names are known."""
    corrects = (
        "the filter already corrects the state at every sample"
        if predictor.filters
        else "multiple shooting carries the model's own state only"
    )
    why = {
        "loss": "its loss is the likelihood of the innovations (drop loss=)",
        "loss_scale": "its loss is the likelihood of the innovations (drop loss_scale=)",
        "weights": "the measurement noise intensities weigh the outputs (drop weights=)",
        "noise": "the measurement noise is estimated with the parameters (drop noise=)",
        "segments": f"{corrects} (drop segments=)",
        "segment_length": f"{corrects} (drop segment_length=)",
        "hessian": "its exact Hessian comes from the transition tensors only (use "
        "hessian='tensors' or 'auto')",
    }
    own = not predictor.takes_loss
    refused = {"loss": own, "loss_scale": own, "weights": own, "noise": own,
               "segments": not predictor.supports_segments,
               "segment_length": not predictor.supports_segments,
               "hessian": not predictor.supports_adjoint}  # fmt: skip
    served = {  # the defaults, which ask nothing of the predictor
        "loss": lambda v: getattr(v, "squared", False) is True,
        "hessian": lambda v: getattr(v, "supports_predictors", False) is True,
        "segments": lambda v: isinstance(v, int) and v == 1,
    }
    for name, value in options.items():
        if value is None or not refused[name] or served.get(name, lambda v: False)(value):
            continue
        value = getattr(value, "name", value)
        shown = value if isinstance(value, str | int | float) else type(value).__name__
        raise ValueError(f"predictor={predictor.name!r} cannot take {name}={shown!r}: {why[name]}")


def no_noise_without_filter(model, predictor, fixed, bounds) -> None:
    """fixed or bounds naming a filter's noise intensity (log_sigma_w_STATE,
    log_sigma_e_OUTPUT) without the filter: one line saying so (it read "names unknown
    params ['log_sigma_e_y']"). A parameter of the model of such a name is its own.
    ``predictor``: a Predictor (its marker ``has_noise_model``)."""
    if predictor.has_noise_model:
        return
    for what, names in (("fixed", fixed or []), ("bounds", bounds or {})):
        noisy = [n for n in ([names] if isinstance(names, str) else names)
                 if str(n).startswith(("log_sigma_w_", "log_sigma_e_"))
                 and n not in model.params]  # fmt: skip
        if noisy:
            raise ValueError(
                f"{what} names {noisy}, noise intensities of a filter: they exist with "
                "predictor='ekf' (output error has no noise model); add it, or drop them"
            )
