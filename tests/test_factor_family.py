"""Factor families on the factor-graph layer (``autotight.graph.Family``): F factors declared at once, evaluated on
stacks, their equations fitted once per family, give the model, lifting and local solver of the same factors
declared one by one; declarations the family fit cannot represent are one-line errors."""

from __future__ import annotations

import types

import numpy as np
import pytest

from autotight import lie
from autotight.errors import ProblemDefinitionError
from autotight.graph import Auxiliary, Euclidean, Factor, Family, Variable, derive
from autotight.graph.assemble import Graph
from autotight.problem import Instance, Param, load

import problems.rotation_averaging as ra


def _module(variables, factors, generate, params=None):
    mod = types.ModuleType("family_toy")
    mod.NAME = "family_toy"
    mod.PARAMS = params or {"M": Param(5)}
    mod.generate = generate
    mod.VARIABLES = variables
    mod.factors = factors
    mod.build, mod.lift, mod.cost, mod.sample, mod.local_solve, mod.recover = derive(variables, factors)
    return load(mod)


# ----------------------------------------------------------------------------- rotation averaging as a family


def _cayley_stack(C, Cm, phi):
    """(I − ½φ^∧) C − (I + ½φ^∧) C̃ column by column on stacks (R, 9)."""
    return (C - Cm - 0.5 * lie.hat_batch(phi) @ (C + Cm)).swapaxes(1, 2).reshape(len(C), 9)


def _cay_inv_stack(C, Cm):
    return np.array([lie.cay_inv(a @ b.T) for a, b in zip(C, Cm)])


def _rotation_family(jacobian: bool = True):
    def factors(inst):
        Cm, W = inst.measurements["C_meas"], inst.measurements["W"]
        aux = Auxiliary({"phi": 3}, value=lambda C, D: _cay_inv_stack(C.x, D),
                        equations=lambda C, a, D: _cayley_stack(C.x, D, a.phi),
                        jacobian=(lambda C, a, D: np.array([lie.jac_cay_inv(p) for p in a.phi])) if jacobian else None)
        yield Family("C", lambda C, a, D: a.phi, data=Cm, type="rotation_meas", weight=W, auxiliary=aux,
                     names=[f"meas_{m}" for m in range(len(Cm))])
    return factors


def _rotation_module(jacobian: bool = True):
    return _module(ra.VARIABLES, _rotation_family(jacobian), ra.generate,
                   {"M": Param(7), "sigma": Param(0.3), "anisotropy": Param(20.0)})


def test_a_family_is_its_factors_declared_one_by_one():
    """Rotation averaging with anisotropic weights: the family's model (blocks, factors, cost, each constraint's
    matrix), lifting, stacked residual and Jacobian, and local solution are the per-factor module's."""
    fam, one = _rotation_module(), load("rotation_averaging")
    inst = one.generate({"M": 7, "sigma": 0.3, "anisotropy": 20.0}, 4)
    a, b = fam.build(inst), one.build(inst)
    assert a.variables.names == b.variables.names
    assert [(f.name, f.type, f.blocks, f.roles) for f in a.factors] == [(f.name, f.type, f.blocks, f.roles)
                                                                         for f in b.factors]
    assert abs(a.Q - b.Q).max() <= 1e-14 * abs(b.Q).max()
    ca, cb = a.primary(), b.primary()
    assert [(c.name, c.factor) for c in ca] == [(c.name, c.factor) for c in cb]
    assert max(abs(x.A - y.A).max() for x, y in zip(ca, cb)) <= 1e-14
    # each family factor keeps its row of the data (the per-factor module declares none)
    assert np.array_equal([f.data for f in a.factors[1:]], inst.measurements["C_meas"].reshape(7, 9))
    rng = np.random.default_rng(2)
    state = fam.sample(inst, rng, inst.truth, 0.5)
    assert np.abs(fam.lift(inst, state) - one.lift(inst, state)).max() <= 1e-14
    assert fam.cost(inst, state) == pytest.approx(one.cost(inst, state), rel=1e-13)
    ga = Graph(ra.VARIABLES, inst.truth, _rotation_family()(inst))
    gb = Graph(ra.VARIABLES, inst.truth, ra.factors(inst))
    (ea, Ja, Wa), (eb, Jb, Wb) = ga.linearize([state["C"]]), gb.linearize([state["C"]])
    assert np.abs(ea - eb).max() <= 1e-14 and np.abs((Ja - Jb).toarray()).max() <= 1e-12
    assert np.abs((Wa - Wb).toarray()).max() <= 1e-12 * np.abs(Wb.toarray()).max()
    start = {"C": lie.exp_so3(np.array([2.0, -1.0, 0.5])) @ inst.truth["C"]}
    ra_, rb_ = fam.local_solve(inst, start), one.local_solve(inst, start)
    assert ra_.converged and rb_.converged and ra_.iterations == rb_.iterations
    assert abs(ra_.cost - rb_.cost) <= 1e-10 * rb_.cost


def test_a_familys_auxiliary_jacobian_by_differences_solves_like_the_declared_one():
    a, b = _rotation_module(), _rotation_module(jacobian=False)
    inst = a.generate({"M": 7, "sigma": 0.3, "anisotropy": 20.0}, 6)
    start = {"C": lie.exp_so3(np.array([1.0, -0.5, 0.3])) @ inst.truth["C"]}
    ga = Graph(ra.VARIABLES, inst.truth, _rotation_family()(inst))
    gb = Graph(ra.VARIABLES, inst.truth, _rotation_family(jacobian=False)(inst))
    Ja, Jb = ga.linearize([start["C"]])[1].toarray(), gb.linearize([start["C"]])[1].toarray()
    assert np.abs(Ja - Jb).max() <= 1e-7 * np.abs(Ja).max()  # central differences, step 1e-6
    ra_, rb_ = a.local_solve(inst, start), b.local_solve(inst, start)
    assert ra_.converged and rb_.converged and abs(ra_.cost - rb_.cost) <= 1e-9 * ra_.cost


# ----------------------------------------------------------------------------- a family without auxiliary blocks


def _points(params, rng):
    p = rng.standard_normal((2, 2))
    anchors = rng.standard_normal((params["M"], 2))
    return Instance("family_toy", dict(params), {"a": anchors, "y": p[0] - anchors + 0.1 * rng.standard_normal(
        (params["M"], 2))}, {"p": p})


POINTS = [Variable("p", Euclidean(2), lifting={"n": lambda p: [p @ p]})]


def _point_data(inst):
    return np.hstack([inst.measurements["a"], inst.measurements["y"]])


def _one_by_one(inst):
    for (a, y) in zip(inst.measurements["a"], inst.measurements["y"]):
        yield Factor("p0", lambda p, a=a, y=y: p.x - a - y, type="offset", weight=2.0)
    yield Factor(("p0", "p1"), lambda p, q: p.x - q.x, type="between")


def _as_family(inst):
    yield Family("p0", lambda p, d: p.x - d[:, :2] - d[:, 2:], data=_point_data(inst), type="offset", weight=2.0)
    yield Factor(("p0", "p1"), lambda p, q: p.x - q.x, type="between")


def test_a_familys_costs_join_its_variables_factor_as_its_factors_one_by_one_do():
    """Affine residuals with data and no auxiliary blocks: their costs join the variable's own factor, as declared
    one by one; the same model and local solution."""
    one, fam = _module(POINTS, _one_by_one, _points), _module(POINTS, _as_family, _points)
    inst = one.generate({}, 3)
    a, b = fam.build(inst), one.build(inst)
    assert [(f.name, f.type, f.blocks) for f in a.factors] == [(f.name, f.type, f.blocks) for f in b.factors]
    assert abs(a.Q - b.Q).max() <= 1e-14 * abs(b.Q).max()
    start = {"p": np.zeros((2, 2))}
    ra_, rb_ = fam.local_solve(inst, start), one.local_solve(inst, start)
    assert abs(ra_.cost - rb_.cost) <= 1e-12 * rb_.cost and np.abs(ra_.state["p"] - rb_.state["p"]).max() <= 1e-12
    assert fam.cost(inst, ra_.state) == pytest.approx(one.cost(inst, ra_.state), rel=1e-13)


# ----------------------------------------------------------------------------- what a family cannot declare


def _bad(**kw):
    def factors(inst):
        Cm = inst.measurements["C_meas"]
        aux = Auxiliary({"phi": 3}, value=lambda C, D: _cay_inv_stack(C.x, D),
                        equations=kw.get("equations", lambda C, a, D: _cayley_stack(C.x, D, a.phi)))
        yield Family("C", kw.get("residual", lambda C, a, D: a.phi), data=Cm, type="rotation_meas", auxiliary=aux,
                     degree=kw.get("degree", 2), names=kw.get("names"))
    return _module(ra.VARIABLES, factors, ra.generate, {"M": Param(3), "sigma": Param(0.1),
                                                        "anisotropy": Param(1.0)})


@pytest.mark.parametrize("kw, message", [
    ({"equations": lambda C, a, D: _cayley_stack(C.x, D, a.phi) * (1 + a.phi[:, :1] ** 2)},
     r"the auxiliary's equations are not polynomials of degree ≤ 2 in the factors' local entries"),
    ({"equations": lambda C, a, D: _cayley_stack(C.x, D * D[:, :1, :1], a.phi), "degree": 1},
     r"the auxiliary's equations are not polynomials .* with coefficients of degree ≤ 1 in their data"),
    ({"residual": lambda C, a, D: a.phi * a.phi}, r"a family's residual must be affine"),
    ({"names": ["a", "a", "b"]}, r"names must be 3 distinct non-empty strings"),
], ids=["cubic-entries", "quadratic-data", "non-affine-residual", "names"])
def test_what_a_family_cannot_declare_is_a_one_line_error(kw, message):
    prob = _bad(**kw)
    with pytest.raises(ProblemDefinitionError, match=rf"^factor family 'rotation_meas': {message}"):
        prob.build(prob.generate({"M": 3}, 0))


def test_the_family_example_on_the_layer_page_is_the_shipped_module():
    """Every line of docs/factor_graph.md's pose-averaging snippet is a line of problems/pose_averaging.py."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    page = (root / "docs" / "factor_graph.md").read_text()
    [snippet] = [c for c in re.findall(r"```python\n(.*?)```", page, re.S) if "pose_meas" in c]
    module = {line.rstrip() for line in (root / "problems" / "pose_averaging.py").read_text().splitlines()}
    lines = [line.rstrip() for line in snippet.splitlines() if line.strip()]
    assert len(lines) >= 7 and [line for line in lines if line not in module] == []
