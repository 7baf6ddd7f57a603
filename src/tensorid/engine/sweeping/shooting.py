"""Multiple shooting: the record split into segments, each with its own initial state.

Experiment e's samples 0..P-1 are cut at k_0 = 0 < k_1 < ... < k_S = P - 1; segment i
starts from its own state s_i at t_{k_i} (s_0 is the experiment's x0, whose free entries
are θ's) and is integrated to t_{k_{i+1}}. The unknowns of the lifted problem are

    z = (for each experiment: free x0, s_1, ..., s_{S-1};  free parameters)

and the continuity conditions are the defects

    c_i(z) = x_end,i(s_i, p) - s_{i+1} = 0,    i = 0 .. S-2.

J(z) is the sum of the segments' costs; each sample is counted once (the sample a
segment shares with the next belongs to the next). Each segment is an ordinary
second-order sweep with local unknowns (s_i, p): its transition matrix at the end is
∂x_end,i/∂(s_i, p), its transition tensor there ∂²x_end,i/∂(s_i, p)², so the Hessian of
the Lagrangian J + λᵀc is the sum of the segments' Hessians plus Σ_i λ_iᵀ T_end,i:
exact, from the same sweeps, all segments of one length in one vmapped call.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ... import _config  # noqa: F401
from .packing import unpack_symmetric
from .sweeps import shared_sweeps


def segment_bounds(P: int, segments: int) -> np.ndarray:
    """Sample indices k_0 = 0 < ... < k_S = P - 1 cutting P samples into ``segments``
    pieces whose interval counts differ by at most one."""
    return np.round(np.linspace(0, P - 1, segments + 1)).astype(int)


def resolve_segments(experiments, segments, segment_length) -> list[int] | None:
    """The number of segments of each experiment, or None for single shooting; one
    clear line for a bad request."""
    E = len(experiments)
    if segments is not None and segment_length is not None:
        raise ValueError("give segments= or segment_length=, not both")
    if segment_length is not None:
        if isinstance(segment_length, bool) or not isinstance(segment_length, int | np.integer):
            raise ValueError(f"segment_length must be a number of samples, got {segment_length!r}")
        if segment_length < 3:
            raise ValueError(f"segment_length must be at least 3 samples, got {segment_length}")
        counts = [max(1, (len(e.t) - 1) // (int(segment_length) - 1)) for e in experiments]
    elif segments is None:
        return None
    else:
        counts = list(segments) if np.ndim(segments) == 1 else [segments] * E
        if len(counts) != E:
            raise ValueError(f"segments has {len(counts)} entries but there are {E} experiments")
        for n in counts:
            if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
                raise ValueError(f"segments must be positive integers, got {segments!r}")
    for e, n in zip(experiments, counts, strict=True):
        if n > 1 and (len(e.t) - 1) // n < 2:
            most = max(1, (len(e.t) - 1) // 2)
            raise ValueError(
                f"segments: {n} segments leave fewer than 2 sample intervals each in an "
                f"experiment of {len(e.t)} samples; use at most {most}"
            )
    counts = [int(n) for n in counts]
    return counts if max(counts) > 1 else None


@dataclass
class _Group:
    """Segments of one kind (first of an experiment or not) and one length, evaluated
    in one vmapped call: their stacked data and where their local unknowns sit in z."""

    first: bool
    members: list[tuple[int, int]]  # (experiment, segment)
    t: jnp.ndarray
    u: jnp.ndarray
    y: jnp.ndarray
    W: jnp.ndarray
    x0: jnp.ndarray  # the fixed x0 values (first segments)
    local: np.ndarray  # (members, K_local) indices into z


@dataclass
class Lifted:
    """The lifted problem's pieces at z: J and its derivatives, the defects c, their
    Jacobian A = ∂c/∂z and, for the exact form, each segment's end tensor for
    ``curvature``."""

    J: float
    g: np.ndarray
    H: np.ndarray
    c: np.ndarray
    A: np.ndarray
    ends: list  # (group, packed T at the ends (members, N, pairs)) or empty

    @property
    def finite(self) -> bool:
        return bool(
            np.isfinite(self.J)
            and np.isfinite(self.g).all()
            and np.isfinite(self.H).all()
            and np.isfinite(self.c).all()
            and np.isfinite(self.A).all()
        )


class Shooting:
    """The segment layout of a Problem and the lifted problem's evaluation.

    Arguments:
        problem: the single-shooting Problem (its θ layout, data, weights, priors).
        counts: the number of segments of each experiment.
    """

    def __init__(self, problem, counts: list[int]):
        self.problem, self.counts = problem, counts
        m = problem.model
        self.N, nx = m.N, len(problem.free_x0)
        self.bounds = [
            segment_bounds(len(e.t), n) for e, n in zip(problem.experiments, counts, strict=True)
        ]
        starts, pos = [], 0
        for n in counts:  # z offset of each experiment's block
            starts.append(pos)
            pos += nx + (n - 1) * self.N
        self.block_start, self.nz_states = starts, pos
        self.nz = pos + len(problem.free_params)
        # where θ's entries (free x0 of each experiment, then parameters) sit in z
        self.theta_index = np.concatenate(
            [self.state_slice(e, 0) for e in range(len(counts))] + [self.param_slice()]
        ).astype(int)
        self.first_sweeps = problem.sweeps
        self.state_sweeps = shared_sweeps(
            m,
            tuple(range(m.N)),
            problem.sweeps.free_params,
            problem.discretisation,
            problem.loss,
        )
        self.groups = self._groups()
        self.defect_rows = [(e, i) for e, n in enumerate(counts) for i in range(n - 1)]

    # -- layout ----------------------------------------------------------------------------
    @property
    def segments(self) -> int:
        """The number of segments, all experiments together."""
        return sum(self.counts)

    def state_slice(self, e: int, i: int) -> np.ndarray:
        """Indices into z of segment i's unknown initial state (free x0 for i = 0)."""
        nx = len(self.problem.free_x0)
        if i == 0:
            return self.block_start[e] + np.arange(nx)
        return self.block_start[e] + nx + (i - 1) * self.N + np.arange(self.N)

    def param_slice(self) -> np.ndarray:
        return np.arange(self.nz_states, self.nz)

    def to_theta(self, z) -> np.ndarray:
        """The user's θ (free x0 of each experiment, free parameters) from z."""
        return np.asarray(z, dtype=float)[self.theta_index]

    def _groups(self) -> list[_Group]:
        pr = self.problem
        found: dict[tuple[bool, int], list] = {}
        for e, k in enumerate(self.bounds):
            for i in range(len(k) - 1):
                found.setdefault((i == 0, int(k[i + 1] - k[i])), []).append((e, i))
        out = []
        for (first, _), members in sorted(found.items()):
            rows = [self._segment_data(e, i) for e, i in members]
            local = np.array(
                [np.concatenate([self.state_slice(e, i), self.param_slice()]) for e, i in members]
            )
            t, u, y, W = (jnp.asarray(np.stack([r[j] for r in rows])) for j in range(4))
            x0 = jnp.asarray(np.stack([pr.x0[e] for e, _ in members]))
            out.append(_Group(first, members, t, u, y, W, x0, local))
        return out

    def _inputs(self, e: int) -> np.ndarray:
        """Experiment e's inputs as the model sees them (delayed), from the Problem."""
        return np.asarray(self.problem.arrays[e][1])

    def _segment_data(self, e: int, i: int):
        ex, k = self.problem.experiments[e], self.bounds[e]
        sl = slice(k[i], k[i + 1] + 1)
        W = np.tile(self.problem.loss_weights, (k[i + 1] - k[i] + 1, 1, 1))
        if i < len(k) - 2:
            W[-1, 0] = 0.0  # the shared sample belongs to the next segment: weight 0
        return ex.t[sl], self._inputs(e)[sl], ex.y[sl], W

    # -- evaluation ------------------------------------------------------------------------
    def evaluate(self, z, exact: bool = True) -> Lifted:
        """J, ∇J, ∇²J (exact, or Gauss-Newton with ``exact`` False), c and A at z."""
        pr, z = self.problem, np.asarray(z, dtype=float)
        nz, N = self.nz, self.N
        J, g, H = 0.0, np.zeros(nz), np.zeros((nz, nz))
        c = np.zeros(len(self.defect_rows) * N)
        A = np.zeros((c.size, nz))
        ends = []
        row = {r: j for j, r in enumerate(self.defect_rows)}
        for gr in self.groups:
            sw = self.first_sweeps if gr.first else self.state_sweeps
            fn = sw.segments if exact else sw.segments_gn
            out = fn(jnp.asarray(z[gr.local]), gr.x0, jnp.asarray(pr.p0), gr.t, gr.u, gr.y, gr.W)
            Jg, gg, Hg, last = (*(np.asarray(a) for a in out[:3]), out[3])
            Kl = gr.local.shape[1]
            Hg = unpack_symmetric(Hg, Kl) if exact else Hg
            J += float(Jg.sum())
            for m, loc in enumerate(gr.local):
                g[loc] += gg[m]
                H[np.ix_(loc, loc)] += Hg[m]
            x_end, dx_end = np.asarray(last[0]), np.asarray(last[1])
            keep = []
            for m, (e, i) in enumerate(gr.members):
                if (e, i) not in row:
                    continue
                r = slice(row[(e, i)] * N, (row[(e, i)] + 1) * N)
                nxt = self.state_slice(e, i + 1)
                c[r] = x_end[m] - z[nxt]
                A[r, gr.local[m]] = dx_end[m]
                A[r, nxt] -= np.eye(N)
                keep.append((m, row[(e, i)]))
            if exact and keep:
                ends.append((gr, np.asarray(last[2]), keep))
        if pr.priors:
            J, g, H = self._priors(z, J, g, H)
        return Lifted(J, g, H, c, A, ends)

    def _priors(self, z, J, g, H):
        """The priors' terms, as the Problem adds them in θ's layout, placed into z's."""
        pr, w = self.problem, self.theta_index
        out = [0.0, np.zeros(pr.K), np.zeros((pr.K, pr.K))]
        pr.add_prior_terms(self.to_theta(z), "JgH", (), out)
        g[w] += out[1]
        H[np.ix_(w, w)] += out[2]
        return J + float(out[0]), g, H

    def curvature(self, lifted: Lifted, v: np.ndarray) -> np.ndarray:
        """Σ_k v_k ∇²c_k (nz, nz): each segment's end tensor contracted with its share of
        v (the -s_{i+1} term of a defect is linear and adds nothing)."""
        out = np.zeros((self.nz, self.nz))
        N = self.N
        for gr, T, keep in lifted.ends:
            Kl = gr.local.shape[1]
            for m, r in keep:
                packed = v[r * N : (r + 1) * N] @ T[m]
                loc = gr.local[m]
                out[np.ix_(loc, loc)] += unpack_symmetric(packed, Kl)
        return out

    # -- the start -------------------------------------------------------------------------
    def start(self, theta, from_data: bool = True) -> np.ndarray:
        """z from the user's θ: every segment's state from a simulation at θ restarted
        at each segment, with the states an output measures directly taken from the
        data (the first segment's free x0 included) unless not ``from_data``."""
        pr = self.problem
        theta = pr.check_theta(theta)
        p, x0 = pr.unpack(theta)
        measured = self.measured_states() if from_data else {}
        z = np.zeros(self.nz)
        z[self.param_slice()] = theta[len(self.counts) * len(pr.free_x0) :]
        free = [pr.model.states.index(n) for n in pr.free_x0]
        for e, k in enumerate(self.bounds):
            ex, s = pr.experiments[e], x0[e].copy()
            u = self._inputs(e)
            for i in range(len(k) - 1):
                for n, o in measured.items():
                    if i > 0 or n in free:
                        s[n] = ex.y[k[i], o]
                z[self.state_slice(e, i)] = s[free] if i == 0 else s
                sl = slice(k[i], k[i + 1] + 1)
                xs, _, _, _ = self.state_sweeps.simulate(
                    jnp.asarray(s), jnp.asarray(p), jnp.asarray(ex.t[sl]), jnp.asarray(u[sl])
                )
                end = np.asarray(xs)[-1]
                s = end.copy() if np.isfinite(end).all() else s  # a blow-up restarts here
        return z

    def measured_states(self) -> dict[int, int]:
        """{state: output} for the states some output equals (y_o = x_n, unit weight),
        found by evaluating the output map at random points."""
        m, pr = self.problem.model, self.problem
        rng = np.random.default_rng(0)
        X = rng.normal(size=(3, m.N)) * (1 + np.abs(pr.x0[0]))
        U = rng.normal(size=(3, m.U))  # an output that reads inputs equals no state alone
        Y = np.array(
            [
                np.asarray(m.h(jnp.asarray(x), jnp.asarray(pr.p0), jnp.asarray(v)))
                for x, v in zip(X, U, strict=True)
            ]
        )
        out: dict[int, int] = {}
        for n in range(m.N):
            for o in range(m.S):
                if pr.weights[o] > 0 and np.allclose(Y[:, o], X[:, n], rtol=1e-12, atol=0):
                    out.setdefault(n, o)
                    break
        return out

    def state_scale(self, z) -> np.ndarray:
        """(N,) typical magnitudes of the states over the segments' starts at z."""
        rows = [z[self.state_slice(e, i + 1)] for e, i in self.defect_rows]
        S = np.array(rows) if rows else np.zeros((1, self.N))
        scale = np.maximum(np.abs(S).max(axis=0), S.std(axis=0))
        return np.where(scale > 0, scale, 1.0)

    # -- a traceable reference, for the tests ------------------------------------------------
    def jax_pieces(self, z):
        """(J, c) at z as traceable JAX functions (plain simulations, no sensitivities)."""
        pr = self.problem
        J, cs = 0.0, []
        w = jnp.asarray(pr.loss_weights)
        for e, k in enumerate(self.bounds):
            ex = pr.experiments[e]
            u = self._inputs(e)
            x = jnp.asarray(pr.x0[e])
            free = [pr.model.states.index(n) for n in pr.free_x0]
            p = (
                jnp.asarray(pr.p0)
                .at[jnp.array(pr.sweeps.free_params, dtype=int)]
                .set(z[self.param_slice()])
            )
            for i in range(len(k) - 1):
                if i == 0:
                    s = x.at[jnp.array(free, dtype=int)].set(z[self.state_slice(e, 0)])
                else:
                    s = z[self.state_slice(e, i)]
                sl = slice(k[i], k[i + 1] + 1)
                xs, ys, _, _ = self.state_sweeps._simulate(s, p, ex.t[sl], u[sl])
                last = i == len(k) - 2
                n = sl.stop - sl.start - (0 if last else 1)  # the shared sample is the next's
                J = J + pr.loss.value(jnp.asarray(ex.y[sl])[:n], ys[:n], w)
                if not last:
                    cs.append(xs[-1] - z[self.state_slice(e, i + 1)])
        theta = z[self.theta_index]
        for i, (mean, sd) in pr.priors.items():
            J = J + pr.noise_variance * ((theta[i] - mean) / sd) ** 2
        return J, (jnp.concatenate(cs) if cs else jnp.zeros(0))
