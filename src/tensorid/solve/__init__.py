"""Solving: the methods as objects stepped by one loop (solvers.py, endings.py), the
trust region and its subproblems, the finite-difference baselines, multiple shooting,
several starts and the workers that run them. It returns plain records (solution.py)
and imports nothing from ``tensorid.analysis`` or ``tensorid.fitting``."""
