"""The paper's Silverbox identification, and the input-offset variant, in Python.

python examples/silverbox_paper.py
"""

import tensorid as ti
from tensorid import benchmarks, datasets


def main() -> None:
    val = datasets.silverbox_validation()
    for label, problem in (
        ("paper's model", benchmarks.silverbox_problem()),
        ("with input offset", benchmarks.silverbox_problem(offset=True)),
    ):
        res = ti.fit(problem, method="newton")
        sim = ti.simulate(problem.model, res.params, [val.measured[0, 0], 0.0], val)
        print(f"{label}: {res.message}, {res.nit} iterations")
        print(res.summary())
        print(
            f"training GOF {res.gof()[0]:.4f}, "
            f"validation GOF {ti.gof(val.measured[:, 0], sim.y[:, 0]):.4f}\n"
        )


if __name__ == "__main__":
    main()
