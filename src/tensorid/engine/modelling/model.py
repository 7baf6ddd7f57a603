"""The grey-box model: dx/dt = F(x, p, u), y = C(x, p), with names for everything.

Models are plain functions written with ``jax.numpy``. Everything tensorid needs
from them (F_x, F_p, F_xx, ..., C_pp) comes from automatic differentiation, so a
model is checked once, symbolically (``jax.eval_shape``), when it is built: wrong
shapes and code JAX cannot trace are reported there, before any compilation.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ... import _config  # noqa: F401  (float64)
from ...functions import ArgumentError

Array = jax.Array

_TRACE_HELP = (
    "Write the model with jax.numpy (import jax.numpy as jnp) instead of numpy or math, "
    "and replace Python `if`/`while` on states or parameters with jnp.where or "
    "jax.lax.cond; index with integers, not with values computed from x, p or u."
)


def _names(kind: str, names: Sequence[str] | None) -> tuple[str, ...]:
    if names is None:
        return ()
    if isinstance(names, str):
        raise TypeError(
            f"{kind} must be a list of names, got the string {names!r}; write {kind}=[{names!r}]"
        )
    out = tuple(names)
    for n in out:
        if not isinstance(n, str) or not n:
            raise TypeError(f"{kind} must be non-empty strings, got {n!r}")
    dup = sorted({n for n in out if out.count(n) > 1})
    if dup:
        raise ValueError(f"{kind} has repeated names: {dup}")
    return out


def _check_delays(delays, inputs) -> dict | None:
    if not delays:
        return None
    if not isinstance(delays, dict):
        raise TypeError(f"input_delays must be a dict {{input: seconds}}, got {delays!r}")
    out = {}
    for name, tau in delays.items():
        if name not in inputs:
            raise ValueError(
                f"input_delays names {name!r}, which is not an input; the inputs are {list(inputs)}"
            )
        try:
            tau = float(tau)
        except (TypeError, ValueError):
            raise ValueError(
                f"input_delays[{name!r}] must be a number of seconds, got {tau!r}"
            ) from None
        if not (np.isfinite(tau) and tau >= 0):
            raise ValueError(f"input_delays[{name!r}] = {tau}: give a finite delay >= 0 seconds")
        out[name] = tau
    return out


@dataclass(frozen=True, eq=False)
class Model:
    """A nonlinear state-space model.

    Arguments:
        rhs: callable ``f(x, p, u) -> dx/dt``
            ``x`` has shape (N,), ``p`` shape (M,), ``u`` shape (U,) (U may be 0);
            must return shape (N,). Written with ``jax.numpy``.
        output: callable ``h(x, p) -> y`` or ``h(x, p, u) -> y``, optional
            Must return shape (S,) (a scalar is accepted when S = 1). May be
            nonlinear and depend on ``p``; with a third argument it reads the inputs
            at each sample (a baseline, a covariate, a feed-through D u), and the
            derivatives go through it as through x and p. Default: every state is an
            output.
        states: list of names
            Names of the x entries, in order. Names must be unique across states and
            params, because bounds and fixed lists refer to both.
        params: list of names
            Names of the p entries, in order.
        inputs: list of names
            Names of the u entries, in order.
        outputs: list of names
            Names of the y entries, in order.
        discrete: bool
            A discrete-time model: ``rhs`` returns x[k+1] = f(x[k], p, u[k]) on the
            experiment's sampling grid (uniform) instead of dx/dt; the derivatives are
            exact by the same recursion (see integrators.DiscreteMap).
        input_delays: dict {input: seconds}, optional
            Known transport or computation delays: the model sees u(t − τ) for that input
            (before the record starts, its first sample). The delayed input is exact at
            every sample instant (the record interpolated at t_k − τ, linearly or held as
            the Problem's interpolation says); between samples the integrator interpolates
            those values, so a delay of whole samples is exact throughout. Known, not
            estimated: the derivatives stay exact.
    """

    rhs: Callable[[Array, Array, Array], Array]
    # (x, p) or (x, p, u); None (every state is an output) is replaced in __post_init__
    output: Callable[..., Array] = None  # type: ignore[assignment]
    states: Sequence[str] = ()
    params: Sequence[str] = ()
    inputs: Sequence[str] = ()
    outputs: Sequence[str] = None  # type: ignore[assignment]
    name: str = "model"
    input_delays: dict | None = None
    discrete: bool = False
    _scalar_output: bool = field(default=False, init=False, repr=False)
    _output_reads_inputs: bool = field(default=False, init=False, repr=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not callable(self.rhs):
            raise TypeError(f"rhs must be a function f(x, p, u), got {type(self.rhs).__name__}")
        states = _names("states", self.states)
        params = _names("params", self.params)
        inputs = _names("inputs", self.inputs)
        if not states:
            raise ValueError("a model needs at least one state: pass states=['x1', ...]")
        if self.output is None:
            outputs = _names("outputs", self.outputs) if self.outputs is not None else states
            if outputs != states:
                raise ValueError(
                    "without an output function every state is an output; "
                    "pass output=h(x, p) to choose other outputs"
                )
            set_(self, "output", _identity_output)
        else:
            if not callable(self.output):
                raise TypeError(
                    f"output must be a function h(x, p), got {type(self.output).__name__}"
                )
            if self.outputs is None:
                raise ValueError("pass outputs=[names] to go with the output function")
            outputs = _names("outputs", self.outputs)
            set_(self, "_output_reads_inputs", _reads_inputs(self.output))
        if not outputs:
            raise ValueError("a model needs at least one output")
        clash = sorted(set(states) & set(params))
        if clash:
            raise ValueError(
                f"names used both as a state and as a parameter: {clash}; rename one of them"
            )
        set_(self, "states", states)
        set_(self, "params", params)
        set_(self, "inputs", inputs)
        set_(self, "outputs", outputs)
        set_(self, "input_delays", _check_delays(self.input_delays, inputs))
        if not isinstance(self.discrete, bool):
            raise TypeError(f"discrete must be True or False, got {self.discrete!r}")
        self._check_shapes()

    # sizes, in the paper's letters
    @property
    def N(self) -> int:
        """Number of states."""
        return len(self.states)

    @property
    def M(self) -> int:
        """Number of parameters."""
        return len(self.params)

    @property
    def U(self) -> int:
        """Number of inputs."""
        return len(self.inputs)

    @property
    def S(self) -> int:
        """Number of outputs."""
        return len(self.outputs)

    def _check_shapes(self) -> None:
        """Trace rhs and output abstractly: catches wrong shapes and untraceable code."""
        x = jax.ShapeDtypeStruct((self.N,), jnp.float64)
        p = jax.ShapeDtypeStruct((self.M,), jnp.float64)
        u = jax.ShapeDtypeStruct((self.U,), jnp.float64)
        sig = f"x of shape ({self.N},), p of shape ({self.M},), u of shape ({self.U},)"
        dx = _trace("rhs", self.rhs, (x, p, u), sig)
        _check_indexing("rhs", self.rhs, (self.N, self.M, self.U), self)
        if dx.shape != (self.N,) and not (self.N == 1 and dx.shape == ()):
            raise ValueError(
                f"rhs returned shape {dx.shape} but the model has {self.N} states "
                f"{list(self.states)}: it must return dx/dt of shape ({self.N},), "
                f"e.g. jnp.stack([...]) with one entry per state"
            )
        if not jnp.issubdtype(dx.dtype, jnp.floating):
            raise TypeError(
                f"rhs returned dtype {dx.dtype}; it must return floats "
                "(use 1.0 instead of 1, and jnp.float64 arrays)"
            )
        if self.reads_inputs:
            y = _trace("output", self.output, (x, p, u), sig)
            _check_indexing("output", self.output, (self.N, self.M, self.U), self)
        else:
            y = _trace("output", self.output, (x, p), sig.rsplit(",", 1)[0])
            _check_indexing("output", self.output, (self.N, self.M), self)
        if y.shape != (self.S,):
            if self.S == 1 and y.shape == ():
                object.__setattr__(self, "_scalar_output", True)
            else:
                raise ValueError(
                    f"output returned shape {y.shape} but the model has {self.S} outputs "
                    f"{list(self.outputs)}: it must return y of shape ({self.S},)"
                )
        if not jnp.issubdtype(y.dtype, jnp.floating):
            raise TypeError(f"output returned dtype {y.dtype}; it must return floats")

    @property
    def compiled_sweeps(self) -> dict:
        """This model's compiled sweeps by (θ layout, discretisation), see
        tensorid.engine.sweeps.shared_sweeps, and its filter models by set of noisy
        states (engine/sweeping/predictors.make_predictor). Per process: not pickled."""
        cache = self.__dict__.get("_compiled_sweeps")
        if cache is None:
            cache = {}
            object.__setattr__(self, "_compiled_sweeps", cache)
        return cache

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != "_compiled_sweeps"}

    def delayed(self, t, u, interpolation: str = "linear", at=None) -> np.ndarray:
        """The inputs the model sees at the sample times t: u(t − τ) for each delayed
        input (``input_delays``), u itself for the others. ``at(times, j)``: input j
        between samples (the smooth interpolations'); without it, linear or held."""
        u = np.asarray(u, dtype=float)
        if not self.input_delays:
            return u
        t = np.asarray(t, dtype=float)
        out = u.copy()
        for name, tau in self.input_delays.items():
            if t.size > 1 and tau >= t[-1] - t[0]:  # the model would see one constant input
                raise ValueError(
                    f"input_delays[{name!r}] = {tau:g} s is not shorter than the record "
                    f"({t[-1] - t[0]:g} s): the model would see only the input's first "
                    "sample; give a shorter delay or a longer record"
                )
            j = self.inputs.index(name)
            if at is not None:
                out[:, j] = at(t - tau, j)
            elif interpolation == "zoh":  # the last sample at or before t − τ
                k = np.searchsorted(t, t - tau * (1 - 1e-12), side="right") - 1
                out[:, j] = u[np.clip(k, 0, len(t) - 1), j]
            else:
                out[:, j] = np.interp(t - tau, t, u[:, j])
        return out

    # Shape-normalised versions used internally: always (N,) and (S,).
    def f(self, x: Array, p: Array, u: Array) -> Array:
        """dx/dt, always of shape (N,)."""
        return jnp.reshape(self.rhs(x, p, u), (self.N,))

    @property
    def reads_inputs(self) -> bool:
        """Whether the output reads the inputs: ``h(x, p, u)``."""
        return self._output_reads_inputs

    def h(self, x: Array, p: Array, u: Array | None = None) -> Array:
        """y, always of shape (S,); ``u`` the inputs at the sample (a march's row,
        whose first U entries are the model's inputs), needed where the output reads
        them."""
        if not self.reads_inputs:
            return jnp.reshape(self.output(x, p), (self.S,))
        if u is None:
            raise ValueError(f"{self.name}: its output reads the inputs; pass them")
        return jnp.reshape(self.output(x, p, u[: self.U]), (self.S,))

    def params_array(self, params, what: str = "params") -> np.ndarray:
        """A dict {name: value} or an array of length M, as a float array in model order."""
        return _named_vector(params, self.params, what)

    def states_array(self, x0, what: str = "x0") -> np.ndarray:
        """A dict {state: value} or an array of length N, as a float array."""
        return _named_vector(x0, self.states, what)

    def __repr__(self) -> str:
        return (
            f"Model({self.name!r}, states={list(self.states)}, params={list(self.params)}, "
            f"inputs={list(self.inputs)}, outputs={list(self.outputs)})"
        )


def _reads_inputs(fn: Callable) -> bool:
    """Whether an output function takes (x, p, u): a ``reads_inputs`` attribute where
    it has one (text equations, wrappers), else three positional parameters."""
    marked = getattr(fn, "reads_inputs", None)
    if marked is not None:
        return bool(marked)
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # a builtin or extension: (x, p) as before
        return False
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    return sum(q.kind in kinds and q.default is q.empty for q in params) >= 3


def _identity_output(x: Array, p: Array) -> Array:
    return x


def _trace(what: str, fn: Callable, args: tuple, sig: str):
    try:
        return jax.eval_shape(fn, *args)
    except (
        jax.errors.ConcretizationTypeError,
        jax.errors.TracerArrayConversionError,
        jax.errors.TracerBoolConversionError,
        jax.errors.TracerIntegerConversionError,
    ) as e:
        raise TypeError(f"{what} cannot be traced by JAX: {type(e).__name__}. {_TRACE_HELP}") from e
    except ArgumentError as e:  # a smooth function's argument: the message says the fix
        raise ValueError(f"{what}: {e}") from e
    except Exception as e:  # the user's own code failed; show what it was called with
        raise TypeError(
            f"{what} failed when called with {sig}: {type(e).__name__}: {e}. {_TRACE_HELP}"
        ) from e


def _check_indexing(what: str, fn: Callable, sizes: tuple[int, ...], model: Model) -> None:
    """JAX clamps out-of-range indices silently (p[7] of 4 parameters reads p[3]), so
    call the function once with NumPy arrays, which raise IndexError instead. Only
    index errors are reported: anything else NumPy cannot do is JAX's business. Text
    equations (``fn.equations``) name their arguments and cannot index past them."""
    if hasattr(fn, "equations"):
        return
    args = [np.full(n, 0.5) for n in sizes]
    try:
        with np.errstate(all="ignore"):
            fn(*args)
    except IndexError as e:
        raise ValueError(
            f"{what} indexes past the end of its arguments ({e}); the model has "
            f"{model.N} states {list(model.states)}, {model.M} params {list(model.params)} "
            f"and {model.U} inputs {list(model.inputs)}"
        ) from e
    except Exception:
        pass


def _named_vector(values, names: Sequence[str], what: str) -> np.ndarray:
    names = list(names)
    if isinstance(values, dict):
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise ValueError(f"{what} names unknown entries {unknown}; known names: {names}")
        missing = [n for n in names if n not in values]
        if missing:
            raise ValueError(f"{what} is missing values for {missing}")
        out = np.empty(len(names))
        for i, n in enumerate(names):
            try:
                out[i] = float(values[n])
            except (TypeError, ValueError):
                raise ValueError(f"{what}: {n}={values[n]!r} is not a number") from None
    else:
        if np.ndim(values):
            out = np.asarray(values, dtype=float).reshape(-1)
        elif len(names) == 1:
            out = np.array([float(values)])
        else:
            raise ValueError(f"{what} must be a dict or an array of {len(names)} values")
        if out.shape != (len(names),):
            raise ValueError(f"{what} has {out.size} values but there are {len(names)}: {names}")
    bad = [n for n, v in zip(names, out, strict=True) if not np.isfinite(v)]
    if bad:
        raise ValueError(f"{what} has non-finite values for {bad}")
    return out
