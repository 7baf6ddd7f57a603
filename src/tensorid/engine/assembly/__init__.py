"""The engine's top (above sweeping/): the Problem that assembles the sweeps into J,
∇J and ∇²J over θ (problem.py, problem_loss.py), θ's layout (layout.py), the priors
and constraints on it (priors.py, constraints.py), a start from an earlier fit
(start.py), and a simulation (simulate.py) with the account of one that failed
(diagnostics.py)."""
