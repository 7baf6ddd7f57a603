"""JAX configuration shared by every module.

Identification needs float64: the Silverbox cost Hessian spans ~18 orders of
magnitude before scaling, and exactness tests compare to 1e-9 relative.
"""

import jax

jax.config.update("jax_enable_x64", True)
