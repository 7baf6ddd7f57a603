"""Fitting: the trust-region driver and its methods, results with their status,
scaling, uncertainty, multi-start and validation on new records."""

from .methods import LOCKSTEP, METHODS, fit, fit_batch
from .options import FitOptions
from .profiles import Profile, profile
from .results import FitInterrupted, FitResult
from .uncertainty import Uncertainty
from .validation import Score

__all__ = [
    "LOCKSTEP",
    "METHODS",
    "FitInterrupted",
    "FitOptions",
    "FitResult",
    "Profile",
    "Score",
    "Uncertainty",
    "fit",
    "fit_batch",
    "profile",
]
