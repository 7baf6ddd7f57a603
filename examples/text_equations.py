"""A model written as text equations: a Van der Pol oscillator with a forcing input,
identified from simulated noisy data with error bars.

    python examples/text_equations.py
"""

import numpy as np

import tensorid as ti


def main() -> None:
    model = ti.model_from_equations(
        rhs={"x": "v", "v": "mu*(1 - x**2)*v - w**2*x + g*u"}, output={"x": "x"}, inputs=["u"]
    )
    truth = {"g": 0.8, "mu": 0.5, "w": 1.3}
    t = np.linspace(0, 20, 400)
    u = np.sin(0.7 * t)
    clean = ti.simulate(model, truth, [1.0, 0.0], ti.Experiment(t, u)).y
    y = clean + 0.02 * np.random.default_rng(0).standard_normal(clean.shape)
    problem = ti.Problem(
        model,
        ti.Experiment(t, u, y),
        p0={"g": 1.0, "mu": 0.3, "w": 1.1},
        x0=[1.0, 0.0],
        free_x0=["x", "v"],
    )
    res = ti.fit(problem)
    print(res.summary())
    print("truth:", truth)


if __name__ == "__main__":
    main()
