"""The names the command line offers for each kind of plug-in, spelled out here so
that building the parser imports no JAX: the losses, predictors, Hessian paths,
fitting methods (and a fleet's) and integration schemes. Each is its registry's
built-in names in the registry's order (tests/test_recipes.py checks that they agree):

    LOSSES       tensorid.engine.losses.REGISTRY       (--loss, a model file's loss)
    PREDICTORS   tensorid.engine.predictors.REGISTRY   (--predictor)
    HESSIANS     tensorid.engine.hessians.REGISTRY     (--hessian)
    METHODS      tensorid.fitting.registry.REGISTRY    (--method), and FLEET_METHODS
    SCHEMES      tensorid.engine.integrators.SCHEMES   (--scheme)
    RESIDUAL_ERRORS  tensorid.population.errors.ERROR_MODELS  (--residual-error)

A plug-in registered at run time is taken by the library by name or as an object;
the command line offers it once its name is here too.
"""

LOSSES = ("squared", "huber", "cauchy", "student-t")
PREDICTORS = ("simulation", "ekf")
HESSIANS = ("auto", "tensors", "adjoint")
METHODS = ("auto", "newton", "newton-cg", "gauss-newton", "fd-bfgs", "fd-lsq")
FLEET_METHODS = ("focei", "laplace")  # a population fit's approximations (population/)
SCHEMES = (
    "euler", "heun", "rk4", "rk38", "implicit-euler", "sdirk2", "sdirk3", "bosh3", "dopri5",
)  # fmt: skip
# a population fit's residual-error models (tensorid.population.errors.ERROR_MODELS)
RESIDUAL_ERRORS = ("additive", "proportional", "combined", "exponential")
