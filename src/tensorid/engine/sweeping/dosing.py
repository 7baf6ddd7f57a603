"""What a fit's records' events do to the model (``Dosing``, the same for every record
of a fit: the target states and what a dose puts into each), the march's view of them
(``channels``: per sample, the bolus amounts, the infusion rates, the reset flags and
values, held over each interval), the jump and the infusions as JAX maps of the
carried state and the parameters (``jump_hook``, ``rhs``), and the checks of what
records with events or gaps go with (the events themselves: events.py).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ..compiling.compiled import on_device
from ..modelling.events import state_index, stopped
from ..schemes.intersample import SMOOTH
from .hessians import get_hessian


@dataclass(frozen=True)
class Dosing:
    """What a record's events do to the model, the same for every record of a fit:
    the target states (D of them) and each target's amount expression.

    The march reads the events as ``channels`` (P, 4D) appended to the inputs and
    held over each interval: per target, the bolus amount at t_h, the infusion rate
    on [t_h, t_h+1), a reset flag and a reset value.

    Arguments:
        targets: the indices of the states that events act on.
        amounts: (target index, expression text) pairs: a dose's amount as the model
            states it, of ``amt`` (the row's amount, or an infusion's rate), the
            model's parameters and inputs; a target without one takes ``amt``.
        inputs: how many of the march's input columns are the model's own (the
            channels follow).
        lags: (target index, expression text) pairs: a dose into that state takes
            effect this long after its time (an absorption lag), an expression of the
            parameters and the inputs. Lagged events are *moving nodes* of the grid
            (``arrays``), placed by the march at their time for the parameters at hand
            (``moving.py``), so that the derivatives are those of the problem posed.
    """

    targets: tuple[int, ...]
    amounts: tuple[tuple[int, str], ...] = ()
    inputs: int = 0
    params: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    states: tuple[str, ...] = ()
    lags: tuple[tuple[int, str], ...] = ()
    durations: tuple[tuple[int, str], ...] = ()
    steady: bool = False  # some records hold steady-state doses (steady.py)

    @property
    def moving(self) -> bool:
        """Whether some events move with the parameters (lags, modelled durations)."""
        return bool(self.lags or self.durations)

    def expressions(self) -> dict:
        """{"doses", "lags", "durations"}: each {state: text}, the expressions as given."""
        return {
            "doses": {self.states[d]: text for d, text in self.amounts},
            "lags": {self.states[d]: text for d, text in self.lags},
            "durations": {self.states[d]: text for d, text in self.durations},
        }

    @property
    def width(self) -> int:
        """The channels' columns as the march reads them (with lags, each interval's
        two ends as (kind, nominal time) besides)."""
        if self.moving:
            return 5 * len(self.targets) + 4
        return 4 * len(self.targets) + (5 if self.steady else 0)

    def arrays(self, e, u) -> tuple[np.ndarray, np.ndarray]:
        """(t, u with the channels) of record e as the sweeps take them, ``u`` the
        model's inputs as the march reads them; with lags, the lagged events' nodes
        follow the record's own P (moving.py)."""
        if not self.moving:
            return e.t, np.concatenate([u, self.channels(e)], axis=1)
        from .moving import node_arrays

        return node_arrays(self, e, u)

    def channels(self, e) -> np.ndarray:
        """(P, 4D) of a record with events on its grid: the bolus amounts, the
        infusion rates running on each interval, the reset flags and values; with
        steady-state doses, 5 more: a flag, the target's position, the amount, the rate
        and the dosing interval of the one at each sample (steady.py)."""
        D, t = len(self.targets), e.t
        out = np.zeros((t.size, 4, D))
        ss = np.zeros((t.size, 5 if self.steady else 0))
        ev = e.events
        if ev is None:
            return np.concatenate([out.reshape(t.size, -1), ss], axis=1)
        pos = {s: i for i, s in enumerate(self.targets)}
        names = self.states
        for k in range(len(ev)):
            h = int(np.searchsorted(t, ev.time[k]))
            kind = ev.kind[k]
            if kind == "reset-all":
                out[h, 2, :], out[h, 3, :] = 1.0, 0.0
                continue
            d = pos[state_index(ev.state[k], names)]
            if kind == "steady-state":
                if ss[h, 0]:
                    raise ValueError(
                        f"record {e.name!r}: two steady-state doses at t = {t[h]:g}; one "
                        "steady state per time is supported (give the other's history)"
                    )
                ss[h] = (1.0, d, ev.amount[k], ev.rate[k], ev.interval[k])
            elif kind in ("bolus", "impulse"):
                if out[h, 0, d]:
                    self._summed(e, d, f"two doses into it at t = {t[h]:g}")
                out[h, 0, d] += ev.amount[k]
            elif kind == "reset":
                out[h, 2, d], out[h, 3, d] = 1.0, ev.amount[k]
            else:  # infusion: its rate on every interval from its start to its end
                end = stopped(ev, k, ev.time[k] + ev.amount[k] / ev.rate[k])
                running = (t >= ev.time[k]) & (t < end - 1e-12 * max(abs(end), 1.0))
                if out[running, 1, d].any():
                    self._summed(e, d, f"infusions into it that overlap at t = {ev.time[k]:g}")
                out[running, 1, d] += ev.rate[k]
        return np.concatenate([out.reshape(t.size, -1), ss], axis=1)

    def _summed(self, e, d: int, what: str) -> None:
        """One line where doses given together (their amounts, or rates, summed before
        the target's expression sees them) meet an expression not linear in amt,
        A(a + b) ≠ A(a) + A(b): each dose would not get its own."""
        text = dict(self.amounts).get(d)
        if text is None or _linear_in_amt(text, (*self.input_names, *self.params)):
            return
        raise ValueError(
            f"record {e.name!r}: doses[{self.states[d]!r}] = {text!r} is not linear in amt, "
            f"and {what} would be summed before it applies; give them at distinct times "
            "(or write the expression linear in amt)"
        )

    def _amount_functions(self, which: str = "doses"):
        """Per target, ``A(amt, p, u)`` in JAX (``which="lags"``: the lag's
        expression, its ``amt`` unused); None where the target has none."""
        import sympy as sp  # here: sympy costs 0.2-0.5 s to import

        from ..modelling.equations import _parse

        names = ["amt", *self.input_names, *self.params]
        symbols = {n: sp.Symbol(n) for n in names}
        given = dict({"doses": self.amounts, "lags": self.lags}.get(which, self.durations))
        fns: list = []
        for d in self.targets:
            if d not in given:
                fns.append(None)
                continue
            expr = _parse(f"{which}[{self.states[d]!r}]", given[d], symbols)
            stray = sorted(str(v) for v in expr.free_symbols if str(v) not in names)
            if stray:
                raise ValueError(
                    f"{which}[{self.states[d]!r}] = {given[d]!r} names {stray}, which are "
                    f"neither 'amt' nor inputs {list(self.input_names)} nor parameters "
                    f"{list(self.params)} of the model"
                )
            fns.append(sp.lambdify([symbols[n] for n in names], expr, modules="jax"))
        return fns

    def functions(self):
        """(jump(x, p, u_row), rate(p, u_row), lags(p, u_row)) of the carried state and
        one row of the march's inputs (the model's own, then the channels)."""
        fns, lag_fns = self._amount_functions(), self._amount_functions("lags")
        dur_fns = self._amount_functions("durations")
        D, U, idx = len(self.targets), self.inputs, np.array(self.targets, dtype=int)

        def amount(q, p, uu):
            parts = []
            for d, fn in enumerate(fns):
                if fn is None:
                    parts.append(q[d])
                    continue
                args = [q[d], *(uu[k] for k in range(U)), *(p[k] for k in range(len(self.params)))]
                parts.append(jnp.where(q[d] != 0, fn(*args) * 1.0, 0.0))
            return jnp.stack(parts)

        def split(uu):
            ch = uu[U : U + 4 * D].reshape(4, D)
            return ch[0], ch[1], ch[2], ch[3]

        def jump(x, p, uu, settle=None):
            if settle is not None:  # a steady-state dose: every state to its cycle's
                x = settle(x, p, uu)
            b, _, r, v = split(uu)
            xs = x[idx]
            return set_at(x, idx, (1.0 - r) * xs + r * v + amount(b, p, uu))

        def of(fns_, p, uu, empty):  # (D,) expressions of p and the inputs
            args = [*(uu[k] for k in range(U)), *(p[k] for k in range(len(self.params)))]
            return jnp.stack([empty + 0.0 * p[0] if f is None else f(0.0, *args) * 1.0
                              for f in fns_])  # fmt: skip

        def shifts(p, uu):  # (lags, durations) (D,) each: 0 and 1 where none is stated
            return of(lag_fns, p, uu, 0.0), of(dur_fns, p, uu, 1.0)

        def rate(p, uu):
            q = split(uu)[1]
            if self.durations:  # the modelled infusions' amounts running, over D(p)
                q = q + uu[U + 4 * D : U + 5 * D] / shifts(p, uu)[1]
            return amount(q, p, uu)

        return jump, rate, shifts, amount


@functools.lru_cache(maxsize=64)
def _linear_in_amt(text: str, names: tuple[str, ...]) -> bool:
    """Whether a dose expression is a(p, u) · amt (``names``: the inputs' and the
    parameters', symbols even where SymPy has a function of that name): then doses
    given together may be summed first."""
    import sympy as sp

    from ..modelling.equations import _parse

    amt = sp.Symbol("amt")
    expr = _parse("doses", text, {"amt": amt, **{n: sp.Symbol(n) for n in names}})
    return sp.simplify(expr - amt * sp.diff(expr, amt)) == 0 and sp.diff(expr, amt, 2) == 0


def dosing_of(
    model,
    experiments,
    doses: Mapping | None = None,
    lags: Mapping | None = None,
    durations: Mapping | None = None,
) -> Dosing | None:
    """The Dosing of a fit's records (None where no record has events and no amount
    or lag expression is given); one line for an expression naming what the model
    lacks."""
    with_events = [e for e in experiments if getattr(e, "events", None) is not None]
    doses, lags, durations = dict(doses or {}), dict(lags or {}), dict(durations or {})
    if not with_events and not doses and not lags and not durations:
        return None
    states = tuple(model.states)
    for what, given in (("doses", doses), ("lags", lags), ("durations", durations)):
        for s in given:
            if s not in states:
                raise ValueError(
                    f"{what} names {s!r}, which is not a state; the model's states are "
                    f"{list(states)}"
                )
    targets: set[int] = {states.index(s) for s in (*doses, *lags, *durations)}
    for e in with_events:
        targets |= set(e.events.targets(states))
    order = tuple(sorted(targets))
    amounts = []
    for s, text in doses.items():
        if not isinstance(text, str):
            raise TypeError(f"doses[{s!r}] must be an expression such as 'F * amt', got {text!r}")
        amounts.append((states.index(s), text))
    timed: dict[str, list] = {"lags": [], "durations": []}
    for what, given in (("lags", lags), ("durations", durations)):
        for s, text in given.items():
            if not isinstance(text, str | int | float) or isinstance(text, bool):
                raise TypeError(f"{what}[{s!r}] must be an expression such as 'D', got {text!r}")
            timed[what].append((states.index(s), str(text)))
    _modelled_need_durations(with_events, states, {s for s, _ in timed["durations"]})
    steady = any("steady-state" in e.events.kind for e in with_events)
    if steady and (timed["lags"] or timed["durations"]):
        raise ValueError(
            "steady-state doses (SS = 1) with lags or modelled durations are not supported "
            "yet: give the dosing history (ADDL with II) instead of SS"
        )
    out = Dosing(
        order, tuple(amounts), len(model.inputs), tuple(model.params), tuple(model.inputs),
        states, tuple(timed["lags"]), tuple(timed["durations"]), steady,
    )  # fmt: skip
    for which in ("doses", "lags", "durations"):  # one line for a bad one, before any work
        out._amount_functions(which)
    return out


def _modelled_need_durations(records, states, stated: set[int]) -> None:
    """One line for an infusion whose duration the model is to set (RATE = −2) into a
    state that ``durations`` does not name."""
    for e in records:
        for k, kind in enumerate(e.events.kind):
            s = e.events.state[k]
            if kind == "modelled-infusion" and state_index(s, states) not in stated:
                name = states[state_index(s, states)]
                raise ValueError(
                    f"record {e.name!r}: the infusion at t = {e.events.time[k]:g} into "
                    f"{name!r} has its duration set by the model (RATE = -2), but no "
                    f"duration is stated for {name!r}: add durations = {{{name!r}: 'D'}} "
                    "(a parameter or an expression)"
                )


def covering(dosing: Dosing | None, model, record) -> Dosing | None:
    """``dosing``, widened to the states ``record``'s events act on (a new record
    scored by a fit's model); None where neither has events."""
    if getattr(record, "events", None) is None:
        return dosing
    if dosing is None:
        return dosing_of(model, [record])
    extra = set(record.events.targets(model.states)) - set(dosing.targets)
    steady = dosing.steady or "steady-state" in record.events.kind
    if not extra and steady == dosing.steady:
        return dosing
    targets = tuple(sorted(set(dosing.targets) | extra))
    return dataclasses.replace(dosing, targets=targets, steady=steady)


def check_events(
    problem, doses, hessian, segments, segment_length, lags=None, durations=None
) -> bool:
    """``problem.dosing`` set (dosing_of), and one line for what records with events or
    gaps cannot go with (a filter, a smooth input interpolation, multiple shooting,
    the adjoint Hessian); returns whether any record has them (then the Hessian is the
    transition tensors')."""
    exps = problem.experiments
    problem.dosing = dosing_of(problem.model, exps, doses, lags, durations)
    if any(e.censored is not None for e in exps) and not problem.population:
        raise ValueError(
            "samples below their quantification limit (censored, Beal's M3) are fitted by "
            "a population's likelihood (population= with method='laplace'); for a least-"
            "squares fit drop them or give their limit as an observation"
        )
    events = problem.dosing is not None
    gaps = events or any(e.observed is not None for e in exps)
    if not gaps:
        return False
    what = "records with events" if events else "records with unobserved samples"
    pr = problem.predictor
    if pr.filters and (events or not pr.takes_gaps):
        raise ValueError(f"{what} are fitted by output error: drop predictor={pr.name!r}")
    if events and problem.discretisation.interpolation not in ("linear", "zoh"):
        raise ValueError(
            f"{what} take interpolation 'linear' or 'zoh', not "
            f"{problem.discretisation.interpolation!r}"
        )
    if (segments not in (None, 1)) or segment_length is not None:
        raise ValueError(f"{what} are fitted by single shooting: drop segments")
    if problem.dosing is not None and (problem.dosing.moving or problem.dosing.steady):
        from ..schemes.integrators import ExplicitRungeKutta

        if not isinstance(problem.discretisation.scheme, ExplicitRungeKutta):
            raise ValueError(
                f"lags, modelled durations and steady-state doses take an explicit "
                f"fixed-step scheme (rk4, rk38, heun, euler), not "
                f"{problem.discretisation.scheme.name!r}"
            )
    path = get_hessian(hessian)
    if not path.takes_gaps:
        raise ValueError(f"{what} take hessian='tensors' (or 'auto'), not {path.name!r}")
    return True


def add_at(x, idx: np.ndarray, v):
    """x with v added at the static positions ``idx`` (along x's last axis): a product
    with a constant one-hot matrix, not a scatter. XLA's CPU backend turns a batched
    scatter into a loop of its own, in every RK stage and every order of derivative: a
    steady-state study's population program held 270 loops where 28 were written, and
    compiled for 31 s. Exact for finite v: the other positions add 0 (an inf in v
    makes NaN of every position, 0 · inf, where a scatter kept it in place: only once
    a dose, a rate or a targeted state has overflowed). One select per target instead
    kept an inf in place, but compiled that study 5 s slower (46.4, 47.1 s against
    41.7, 41.8 s, alternating)."""
    onto = jnp.asarray(np.eye(x.shape[-1])[idx], dtype=x.dtype)
    return x + v @ onto


def set_at(x, idx: np.ndarray, v):
    """x with the positions ``idx`` replaced by v (as ``add_at``, without a scatter; a
    non-finite value at one target makes NaN of the other targets)."""
    onto = np.eye(x.shape[-1])[idx]
    return jnp.where(onto.any(axis=0), v @ jnp.asarray(onto, dtype=x.dtype), x)


@functools.cache
def maps(dosing: Dosing):
    """``dosing.functions()``, made once per Dosing (SymPy's lambdify is slow)."""
    return dosing.functions()


def rhs(model, dosing: Dosing | None, uu):
    """(x, p) ↦ the model's own F, with the infusions running on the interval where
    the records have events (``uu``: the model's inputs, then the events' channels)."""
    if dosing is None:
        return lambda x, p_: model.f(x, p_, uu)
    rate = maps(dosing)[1]
    U, idx = model.U, np.array(dosing.targets, dtype=int)
    if dosing.moving:  # on the march's unit grid: dx/dσ = (the interval's length) · F
        from .moving import length

        lag = maps(dosing)[2]
        return lambda x, p_: (
            length(dosing, lag, p_, uu) * add_at(model.f(x, p_, uu[:U]), idx, rate(p_, uu))
        )
    return lambda x, p_: add_at(model.f(x, p_, uu[:U]), idx, rate(p_, uu))


def jump_hook(dosing: Dosing | None, p, push=None, settle=None):
    """``march``'s jump hook: None without events; else the events at a sample, with
    ``push(fn, state)`` carrying an augmented state's sensitivities through the map
    z ↦ fn(z, p) (None: a plain state); ``settle``: steady-state doses (steady.py)."""
    if dosing is None:
        return None
    jmap = maps(dosing)[0]
    if push is None:
        return lambda state, uh: jmap(state, p, uh, settle)
    return lambda state, uh: push(lambda z, p_: jmap(z, p_, uh, settle), state)


def masks_records(problem, segments) -> bool:
    """Whether a problem's one record passes y with a mask (``measured``) although it
    has no gaps: output error, single shooting, no events, inputs between samples
    from their two neighbours (linear or held: a smooth interpolation is fitted to
    the whole record), and a Hessian path with the marker ``masks_one_record``. The
    model-error check's halves are then the record with its other samples masked,
    fitted by the programs the fit compiled instead of new ones of a half's length
    (about a second on a first fit). Several records are the check's parts as they
    are: they keep y plain."""
    if len(problem.experiments) != 1 or segments or problem.predictor.filters:
        return False
    smooth = problem.discretisation.interpolation in SMOOTH
    return problem.dosing is None and not smooth and problem.hessian_path.masks_one_record


def measured(e, size: int, masked: bool = False):
    """y as the sweeps take it: the array, or {"y", "mask"} for a record with gaps (or
    with ``size`` rows, more than its own: a lagged event's nodes, not observed), and
    for every record where ``masked`` (Problem.masked: a part of it is then fitted by
    the same compiled programs)."""
    if e.observed is None and size == e.P and not masked:
        return on_device(e.y)
    mask = np.ones_like(e.y) if e.mask is None else e.mask
    pad = np.zeros((size - e.P, e.y.shape[1]))
    y, mask = np.concatenate([e.y, pad]), np.concatenate([mask, pad])
    return {"y": on_device(y), "mask": on_device(mask)}
