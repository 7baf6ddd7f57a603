# The Silverbox (an electronic Duffing oscillator) as text equations, with the
# input offset u0 estimated: m y'' + d y' + (a + b y^2) y = u - u0.
# Fit:  tensorid fit examples/silverbox/model.py examples/silverbox/train.csv \
#           --validate examples/silverbox/validate.csv --out silverbox-fit
rhs = {"y": "ydot", "ydot": "(u - u0 - d*ydot - a*y - b*y**3)/m"}
output = {"y": "y"}
inputs = ["u"]
params = ["m", "d", "a", "b", "u0"]

p0 = {"m": 5.1025e-6, "d": 2.15e-4, "a": 0.968, "b": 3.976, "u0": 0.0}
x0 = {"y": 0.0, "ydot": 0.0}
free_x0 = ["y", "ydot"]
bounds = {"m": (1e-7, 1e-4), "d": (0.0, 1e-2)}
