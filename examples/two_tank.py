"""The paper's two-tank identification: Newton and Gauss-Newton from the paper's guess.

python examples/two_tank.py
"""

import numpy as np

import tensorid as ti
from tensorid import benchmarks


def main() -> None:
    problem = benchmarks.two_tank_problem()
    for method in ("newton", "gauss-newton"):
        res = ti.fit(problem, method=method)
        x = res.simulate()[0].x
        print(f"{method}: cost {res.cost:.6g}, GOF {res.gof()[0]:.4f}, {res.nit} iterations")
        print("  params:", {k: round(v, 5) for k, v in res.params.items()})
        print("  lowest simulated levels:", np.round(x.min(axis=0), 5))


if __name__ == "__main__":
    main()
