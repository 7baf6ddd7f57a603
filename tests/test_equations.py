"""Text equations read directly (plain arithmetic, params given) and through SymPy
(everything else) give the same model."""

import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti
from tensorid.engine import equations

PLAIN = [
    "(u - u0 - d*v - a*y - b*y**3)/m",
    "-a*y**2 + 2/3*v - u**-1",
    "Max(y, a, 2*v) - Min(v, b)",
    "atan2(y, a) + pi*sqrt(Abs(v)) - abs(b)",
    "exp(-y)/2 + log(1 + v**2) + tanh(a*y) * sinh(b) - cosh(v)",
    "sin(y)*cos(v) + tan(a) + asin(0.1*y) + acos(0.2) + atan(v) + sign(y - v)",
    "asinh(y) + acosh(2 + v**2) + atanh(0.3) - +y",
    "y**0.5 + 3**2 - 1e-3*u",
]


@pytest.mark.parametrize("text", PLAIN)
def test_plain_equations_are_read_directly_and_match_sympy(text):
    names = dict(states=["y", "v"], inputs=["u"], params=["m", "d", "a", "b", "u0"])
    rhs = {"y": "v", "v": text}
    direct = equations._direct(rhs, {"y": "y"}, **names)
    assert direct is not None, "plain arithmetic must not need SymPy"
    f_direct, _, _ = direct
    f_sympy, _, _ = equations._with_sympy(rhs, {"y": "y"}, **names)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = rng.uniform(0.2, 0.9, 2)
        p = rng.uniform(0.5, 1.5, 5)
        u = rng.uniform(0.5, 1.0, 1)
        np.testing.assert_allclose(f_direct(x, p, u), f_sympy(x, p, u), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize(
    "text",
    [
        "y^2",  # SymPy reads ^ as a power
        "log(y, 2)",  # a logarithm to a base
        "k*y",  # a name not declared: SymPy says which
        "erf(y)",  # a function not in the direct list
        "y if v else 0",
    ],
)
def test_anything_else_goes_through_sympy(text):
    assert equations._direct({"y": text}, {"y": "y"}, ["y"], [], ["a"]) is None


def test_sympy_is_not_imported_for_plain_equations(tmp_path):
    code = (
        "import sys, tensorid as ti\n"
        "m = ti.model_from_equations({'y': 'v', 'v': '-k*y - c*v + u'}, {'y': 'y'}, ['u'], "
        "['k', 'c'])\n"
        "print('sympy' in sys.modules, m.params)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split()[0] == "False", out.stdout


def test_the_direct_path_keeps_the_checks():
    m = ti.model_from_equations({"x": "-k*x + u"}, {"y": "x + u"}, ["u"], ["k"])
    assert (
        m.reads_inputs and not ti.model_from_equations({"x": "-k*x + u"}, None, ["u"]).reads_inputs
    )
    y = m.h(jnp.array([1.0]), jnp.array([0.5]), jnp.array([2.0, 99.0]))  # a march's row
    assert float(y[0]) == 3.0
    with pytest.raises(ValueError, match="'q' .* is not a state, input or parameter"):
        ti.model_from_equations({"x": "-k*x + q"}, None, [], ["k"])
    m = ti.model_from_equations({"x": "-k*x"}, None, [], ["k"])
    assert m.rhs.equations == {"x": "-k*x"}


def test_what_the_direct_path_cannot_bind_goes_to_sympy_and_still_works():
    one = (np.array([1.0]), np.array([2.0]), np.array([]))
    # a large integer is a float, as SymPy evaluates it
    m = ti.model_from_equations({"x": "-k*x/10**20"}, None, [], ["k"])
    np.testing.assert_allclose(m.f(*one), [-2e-20])
    # a state called like a builtin, a keyword declared, a name that is not a string
    m = ti.model_from_equations({"list": "-k*list"}, None, [], ["k"])
    np.testing.assert_allclose(m.f(*one), [-2.0])
    assert equations._direct({"x": "-k*x"}, {"x": "x"}, ["x"], [], ["k", "lambda"]) is None
    assert equations._direct({1: "-k"}, {"x": "x"}, [1], [], ["k"]) is None
    # an expression too long for Python's parser: SymPy reads it
    long = " + ".join(f"{i}.5*x" for i in range(400))
    assert equations._direct({"x": long}, {"x": "x"}, ["x"], [], ["k"]) is None
    m = ti.model_from_equations({"x": long}, None, [], ["k"])
    np.testing.assert_allclose(m.f(np.array([1.0]), np.array([1.0]), np.array([])), [80000.0])


def test_integer_exponents_stay_integer_powers():
    import jax

    f, _, _ = equations._direct({"x": "x**3 - x**-1"}, {"x": "x"}, ["x"], [], [])
    text = str(jax.make_jaxpr(f)(np.ones(1), np.ones(0), np.ones(0)))
    assert "integer_pow[y=3]" in text and "integer_pow[y=-1]" in text
