"""Which of ``tensorid fit``'s flags a fleet's fit (population or individual
parameters) honours, and the one line that refuses each of the others before any work
(they were accepted and dropped without a word). Honoured besides the data's and the
model's: --validate (held-out units: population/validation.py), --profile (typical
values, ω, shared parameters: population/profiles.py), --data-sensitivity (which unit
moves the estimates: population/influence.py), --starts, --spread and --seed (starts
of the typical values, shared parameters and ω: population/start.py), the integration
and iteration limits, --method focei/laplace, --workers and --scheduler.
tests/test_fleet_flags.py walks every flag of the parser against this table."""

from __future__ import annotations

# flag -> (args attribute, the values that ask for nothing a fleet lacks, why a fleet's
# fit does not take another)
REFUSED: dict[str, tuple[str, tuple, str]] = {
    "--init-window": ("init_window", (None,),
        "a held-out unit starts from the model file's x0 (its expressions of the unit's "
        "covariates) and its η̂ is estimated on all its samples"),
    "--horizon": ("horizon", (None,),
        "a fleet's units are predicted by simulation from their x0 (output error), so "
        "every horizon is the simulation"),
    "--segments": ("segments", (None,),
        "multiple shooting is not run for a fleet: each unit is simulated whole"),
    "--segment-length": ("segment_length", (None,),
        "multiple shooting is not run for a fleet: each unit is simulated whole"),
    "--no-polish": ("no_polish", (False,),
        "multiple shooting (which the polish follows) is not run for a fleet"),
    "--hessian": ("hessian", ("auto",),
        "a population fit's exact Hessian is its own (nested derivatives through every "
        "unit's inner solve), not one of --hessian's paths"),
    "--loss": ("loss", (None, "squared"),
        "a population fit is a likelihood with its residual-error model "
        "(--residual-error), not a loss"),
    "--loss-scale": ("loss_scale", (None,), "a population fit takes no robust loss"),
    "--predictor": ("predictor", (None, "simulation"),
        "a population fit is of output error: each unit simulated from its x0"),
    "--process-noise": ("process_noise", (None,), "a population fit runs no filter"),
    "--measurement-noise": ("measurement_noise", (None,),
        "a population fit estimates each output's residual error itself "
        "(--residual-error chooses its model)"),
    "--residual-lags": ("residual_lags", (None,),
        "the residual tests of single records are not made for a fleet; its residuals "
        "are in observations.csv (CWRES, NPDE) and residuals.png"),
    "--no-model-check": ("no_model_check", (False,),
        "a fleet's fit makes no model-error check (its check of the substeps stays; "
        "--substeps chooses them)"),
    "--batch": ("batch", (None,),
        "a fleet's starts run one after another, each spreading its units over the "
        "workers (--workers, --scheduler), not in lock-step batches"),
}  # fmt: skip


def check_fleet_flags(args) -> None:
    """The first flag given that a fleet's fit does not take: one line naming it."""
    for flag, (attr, accepted, why) in REFUSED.items():
        value = getattr(args, attr, accepted[0])
        if not any(value is a or (type(value) is type(a) and value == a) for a in accepted):
            raise ValueError(
                f"{flag}: {why}; drop {flag} for a fit with population or individual parameters"
            )
