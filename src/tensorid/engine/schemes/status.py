"""How a fit or a simulation ended: one ``Status`` member each, with its message.

The compiled integrators report failures as small integers (``Status.code``) next to
their results, so that what went wrong is read from the computation itself instead
of being guessed afterwards from NaN.
"""

from __future__ import annotations

import enum


class Status(enum.Enum):
    """How a fit or a simulation ended (cf. optimistix's ``RESULTS``).

    ``success`` says whether the ending counts as converged; ``message`` is the text a
    user reads. Integrator failures carry the integer ``code`` that the compiled
    march returns; every other member has code -1.
    """

    # a simulation
    OK = ("ok", True, 0)
    NONFINITE_STATE = ("the state became non-finite", False, 1)
    STEP_LIMIT = ("the adaptive integrator reached its step limit within one sample", False, 2)
    STEP_UNDERFLOW = ("the adaptive integrator's step size underflowed", False, 3)
    NEWTON_FAILED = ("an implicit stage's Newton iteration did not converge", False, 4)
    NONFINITE_OUTPUT = ("the outputs became non-finite although the states are finite", False, -1)
    # a fit that converged
    GTOL = ("converged: projected gradient below gtol", True, -1)
    FTOL = ("converged: relative cost decrease below ftol", True, -1)
    XTOL = ("converged: step below xtol", True, -1)
    ROUNDING_FLOOR = ("converged: the cost is at the rounding floor of the data", True, -1)
    NO_FURTHER_DECREASE = ("converged: no further decrease predicted", True, -1)
    MACHINE_PRECISION = (
        "converged: no further decrease possible at machine precision",
        True,
        -1,
    )
    BASELINE_CONVERGED = ("converged", True, -1)  # a SciPy baseline's own criterion
    # a fit that stopped short
    MAXITER = ("iteration limit reached", False, -1)
    NO_PREDICTED_DECREASE = (
        "stopped: the model predicts no decrease, although the gradient is not small "
        "(check the problem's scaling)",
        False,
        -1,
    )
    RADIUS_COLLAPSED = (
        "stopped: the trust region collapsed without a decrease as large as its model "
        "predicted (the cost may be noisy, its derivatives inconsistent, or the "
        "simulation fails near this point)",
        False,
        -1,
    )
    NONFINITE_START = (
        "the cost is not finite at the start: the simulation blows up there; choose "
        "another initial guess or tighter bounds",
        False,
        -1,
    )
    BASELINE_STOPPED = ("stopped", False, -1)  # a SciPy baseline gave up in its own way
    SOLVER_FAILED = ("stopped: the optimiser raised an error; the best point is kept", False, -1)
    ALL_STARTS_FAILED = ("no start gave a finite cost", False, -1)
    DEFECTS_REMAIN = (
        "stopped: multiple shooting left continuity defects above their tolerance",
        False,
        -1,
    )
    CONSTRAINTS_VIOLATED = (
        "stopped: the constraints are not met to their tolerance (they may contradict "
        "each other or the bounds)",
        False,
        -1,
    )
    # a fit stopped from outside: the best point found so far is kept
    INTERRUPTED = ("interrupted; the best point found so far is kept", False, -1)
    WORKERS_LOST = (
        "the workers stopped answering; the best of the starts that finished is kept",
        False,
        -1,
    )

    def __init__(self, message: str, success: bool, code: int):
        self.message = message
        self.success = success
        self.code = code

    def describe(self, detail: str = "") -> str:
        """The message of this ending, with a detail appended when there is one."""
        return f"{self.message} ({detail})" if detail else self.message

    @classmethod
    def from_code(cls, code: int) -> Status:
        """The integrator status for a code returned by the compiled march."""
        for s in cls:
            if s.code == code:
                return s
        raise ValueError(f"unknown integrator failure code {code}")

    def __str__(self) -> str:
        return self.name.lower()
