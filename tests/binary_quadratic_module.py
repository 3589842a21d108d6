"""A ±1 quadratic program: min sᵀWs + bᵀs over s ∈ {±1}ⁿ.

Lifting x = [h, s_1, …, s_n]; primary constraints s_i² = h².  No other quadratic relation holds on {±1}ⁿ, so
Shor's relaxation (Goemans–Williamson's) is all there is: tight on some instances, not on others.
"""

import itertools

import numpy as np

from autotight.model import Constraint, Factor, Model, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Param

PARAMS = {
    "n": Param(3, "number of ±1 variables", low=2),
    "field": Param(0.5, "standard deviation of each entry of b", low=0.0),
    "frustration": Param(0.0, "coupling added to every off-diagonal entry of W (large: every s_i wants "
                              "the opposite sign of every other, which n = 3 cannot satisfy)", low=0.0),
}


def _best(W, b):
    states = [np.array(s, float) for s in itertools.product([-1.0, 1.0], repeat=len(b))]
    return min(states, key=lambda s: s @ W @ s + b @ s)


def generate(params, rng):
    n = params["n"]
    W = rng.standard_normal((n, n))
    W = (W + W.T) / 2 + params["frustration"] * np.ones((n, n))
    np.fill_diagonal(W, 0.0)
    b = params["field"] * rng.standard_normal(n)
    return Instance("binary_quadratic", dict(params), {"W": W, "b": b}, {"s": _best(W, b)})


def _blocks(n):
    return [f"s{i}" for i in range(n)]


def build(inst):
    W, b = inst.measurements["W"], inst.measurements["b"]
    V = Variables([(s, 1) for s in _blocks(len(b))])
    factors = []
    for i, s in enumerate(_blocks(len(b))):
        square = Constraint(QuadForm(V).add(s, s, 1.0).const(-1.0).matrix(), 0.0, name=f"{s}²=h²")
        factors.append(Factor(f"spin_{i}", "spin", ("h", s), cost=QuadForm(V).linear(s, b[i]).matrix(),
                              constraints=[square], roles=("h", "s")))
    for i, j in itertools.combinations(range(len(b)), 2):
        si, sj = f"s{i}", f"s{j}"
        factors.append(Factor(f"coupling_{i}_{j}", "coupling", ("h", si, sj),
                              cost=QuadForm(V).add(si, sj, 2.0 * W[i, j]).matrix(), roles=("h", "s", "t")))
    return Model(V, factors)


def lift(inst, state):
    V = Variables([(s, 1) for s in _blocks(len(state["s"]))])
    return V.assemble({s: np.array([v]) for s, v in zip(_blocks(len(state["s"])), state["s"])})


def cost(inst, state):
    s = np.asarray(state["s"], float)
    return float(s @ inst.measurements["W"] @ s + inst.measurements["b"] @ s)


def sample(inst, rng, nominal, spread):
    return {"s": rng.choice([-1.0, 1.0], size=len(nominal["s"]))}


def local_solve(inst, init, **options):
    s = _best(inst.measurements["W"], inst.measurements["b"])
    return LocalResult({"s": s}, cost(inst, {"s": s}), 2 ** len(s), True)


def recover(inst, Theta):
    x = np.asarray(Theta, float).reshape(-1)
    return {"s": np.where(x[1:] >= 0, 1.0, -1.0)}
