"""The sweeps (above schemes/): the augmented system x, dx = ∂x/∂θ, d2x = ∂²x/∂θ²
marched with J, ∇J and ∇²J (sweeps.py, second_order.py, packing.py), the second-order
adjoints and the Hessian paths (adjoint.py, hessians.py), the output sensitivities
(output_sensitivity.py), the multiple-shooting segments (shooting.py), what a sample's
misfit costs (losses.py), how the state is carried between samples (predictors.py),
and what the records' events do to the march (dosing.py, moving.py, steady.py)."""
