"""`fit --fix NAME=VALUE --free NAME --bounds NAME=LO:HI`: trying a parameter (or, with
a filter, a noise intensity: log σ) fixed, free or bounded without editing the
model file. The command line wins over the
file; what it changed is recorded in fit.json ("overrides")."""

from __future__ import annotations

import warnings
from dataclasses import replace

from ..engine.sweeping.predictors import noise_names as predictor_noise_names
from .files import ModelSpec


def noise_names(spec: ModelSpec) -> list[str]:
    """The filter's noise intensities a model could have (with --predictor ekf):
    log σ_w of each state, log σ_e of each output."""
    process, measurement = predictor_noise_names(spec.model, spec.model.states, spec.model.outputs)
    return process + measurement


def given_once(option: str, pairs) -> dict:
    """--fix or --bounds as a dict, each name given once: repeated, the last won
    without a word (--fix a=1 --fix a=0.9 fitted with 0.9)."""
    out: dict = {}
    for name, value in pairs or []:
        if name in out:
            raise ValueError(f"{option} gives {name} twice; give it once")
        out[name] = value
    return out


def _check_names(spec: ModelSpec, fix: dict, free: list, bounds: dict) -> None:
    m = spec.model
    known = list(m.params) + list(m.states) + noise_names(spec)
    for option, names in (("--fix", fix), ("--free", free), ("--bounds", bounds)):
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(
                f"{option} names {unknown}, which {spec.path} does not have; its parameters "
                f"are {list(m.params)}, its states {list(m.states)} and, with a filter, "
                "its noise intensities log_sigma_w_STATE and log_sigma_e_OUTPUT"
            )
    both = sorted(set(fix) & set(free))
    if both:
        raise ValueError(f"{both} given to both --fix and --free; keep one of them")
    states = [n for n in bounds if n in m.states]
    if states:
        raise ValueError(f"--bounds {states}: bounds apply to parameters, not initial states")
    for name, (lo, hi) in bounds.items():
        if not lo < hi:
            raise ValueError(f"--bounds {name}={lo:g}:{hi:g}: LO must be below HI")


def _outside(spec: ModelSpec, name: str, value: float, bound) -> None:
    """--fix outside the model file's bounds: held there as asked, with a word (a
    fixed parameter drops its bounds, so the file's would not have said it)."""
    lo, hi = bound if bound is not None else (None, None)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        warnings.warn(
            f"--fix {name}={value:g} is outside {spec.path}'s bounds for {name} "
            f"({lo}, {hi}): held there as asked; fix it inside them if they are physical",
            UserWarning,
            stacklevel=2,
        )


def overridden(spec: ModelSpec, fix: dict, free: list, bounds: dict) -> tuple[ModelSpec, dict]:
    """(the model file's settings with the command line's changes, those changes as
    fit.json records them). A fixed parameter loses the file's bounds; bounds on a
    parameter that stays fixed are refused with the way out (--free)."""
    _check_names(spec, fix, free, bounds)
    m = spec.model
    p0 = None if spec.p0 is None and not set(fix) & set(m.params) else dict(spec.p0 or {})
    x0 = dict(spec.x0 or {})
    fixed, free_x0, box = list(spec.fixed), list(spec.free_x0), dict(spec.bounds)
    noise = noise_names(spec)
    for name, value in fix.items():
        if name in noise:  # held at exp(value) (fit_setup puts it in the filter's noise)
            fixed += [name] if name not in fixed else []
            box.pop(name, None)
        elif name in m.params and p0 is not None:
            p0[name] = value
            fixed += [name] if name not in fixed else []
            _outside(spec, name, value, box.pop(name, None))
        else:
            x0[name] = value
            free_x0 = [n for n in free_x0 if n != name]
    for name in free:
        if name in m.params or name in noise:
            fixed = [n for n in fixed if n != name]
        elif name not in free_x0:
            free_x0.append(name)
    held = [n for n in bounds if n in fixed]
    if held:
        how = "--fix" if set(held) & set(fix) else f"the model file {spec.path}"
        raise ValueError(
            f"--bounds {held}: fixed by {how}; add --free {' --free '.join(held)} to "
            "estimate within the bounds, or drop --bounds"
        )
    box.update(bounds)
    new = replace(spec, p0=p0, x0=x0, fixed=fixed, free_x0=free_x0, bounds=box)
    record = {"fix": fix, "free": list(free), "bounds": {k: list(v) for k, v in bounds.items()}}
    return new, {k: v for k, v in record.items() if v}
