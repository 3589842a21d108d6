"""Factor families on the factor-graph layer (``autotight.graph.Family``): F factors declared at once, evaluated on
stacks, their equations fitted once per family, give the model, lifting and local solver of the same factors
declared one by one; declarations the family fit cannot represent are one-line errors."""

from __future__ import annotations

import types

import numpy as np
import pytest

from autotight import lie
from autotight.errors import ProblemDefinitionError
from autotight.graph import Auxiliary, Euclidean, Factor, Family, Rotation, Variable, derive
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
    from doc_snippets import missing_lines

    lines, missing = missing_lines("pose_meas", "pose_averaging")
    assert len(lines) >= 7 and missing == []


# ----------------------------------------------------------------------------- a chain written element by element


def _chain(params, rng):
    K = params["M"]
    C = np.array([lie.exp_so3(np.array([0.0, 0.0, a]))[:2, :2] for a in rng.uniform(-1, 1, K)])
    p = rng.standard_normal((K, 2))
    meas = {"d": rng.standard_normal((K, 2)), "u": rng.standard_normal((K - 1, 2))}
    return Instance("family_toy", dict(params), meas, {"C": C, "p": p})


CHAIN = [Variable("C", Rotation(2), block="c", element="P{i}_{block}", factor="rot"),
         Variable("p", Euclidean(2), element="P{i}_{block}")]


def _chain_factors(aux_names: bool = True, roles=("h", "c", "p", "c'", "p'", "w")):
    def factors(inst):
        K = len(inst.truth["C"])
        rotated = lambda C, D: np.einsum("rij,rj->ri", C.x, D)  # noqa: E731
        yield Family([(f"C{k}", f"p{k}") for k in range(K)], lambda C, p, z, D: z.z - p.x, data=inst.measurements["d"],
                     type="meas", auxiliary=Auxiliary({"z": 2}, value=lambda C, p, D: rotated(C, D),
                                                      equations=lambda C, p, z, D: z.z - rotated(C, D)),
                     names=[f"meas_{k}" for k in range(K)], aux_names=[str(k) for k in range(K)] if aux_names else None,
                     clique=True)
        yield Family([(f"C{k}", f"p{k}", f"C{k + 1}", f"p{k + 1}") for k in range(K - 1)],
                     lambda C1, p1, C2, p2, w, D: w.w, data=inst.measurements["u"], type="step",
                     auxiliary=Auxiliary({"w": 2}, value=lambda C1, p1, C2, p2, D: p2.x - p1.x - D,
                                         equations=lambda C1, p1, C2, p2, w, D: w.w - p2.x + p1.x + D),
                     names=[f"step_{k + 1}_{k}" for k in range(K - 1)],
                     aux_names=[f"{k + 1}_{k}" for k in range(K - 1)] if aux_names else None, roles=roles)
    return factors


def test_a_chain_by_element_is_the_same_model_in_the_papers_order():
    """``derive(by_element=True)`` with ``Variable.element``/``factor`` and ``Family.aux_names``/``roles``: pose k's
    blocks and rotation factor before pose k + 1's, each rotation factor right before its measurement factor, the
    named auxiliary blocks and the declared roles; the same model as declared variable by variable, up to the order
    of the blocks (the same cost and constraint values at a lifted sample, constraint by constraint)."""
    K = 4
    inst = _chain({"M": K}, np.random.default_rng(0))
    parts = derive(CHAIN, _chain_factors(), by_element=True)
    plain = derive(CHAIN, _chain_factors())
    a, b = parts.build(inst), plain.build(inst)
    assert a.variables.names[:5] == ["h", "P0_c", "P0_p", "P1_c", "P1_p"]
    assert a.variables.names[1 + 2 * K:] == [f"z_{k}" for k in range(K)] + [f"w_{k + 1}_{k}" for k in range(K - 1)]
    assert b.variables.names[:3] == ["h", "P0_c", "P1_c"]
    assert sorted(a.variables.names) == sorted(b.variables.names)
    assert [f.name for f in a.factors] == [n for k in range(K) for n in (f"rot_{k}", f"meas_{k}")] + \
        [f"step_{k + 1}_{k}" for k in range(K - 1)]
    assert [f.name for f in b.factors] == [f"rot_{k}" for k in range(K)] + [f"meas_{k}" for k in range(K)] + \
        [f"step_{k + 1}_{k}" for k in range(K - 1)]
    assert {f.roles for f in a.factors if f.type == "step"} == {("h", "c", "p", "c'", "p'", "w")}
    assert a.factor("step_1_0").blocks == ("h", "P0_c", "P0_p", "P1_c", "P1_p", "w_1_0")
    assert a.cliques == [("h", f"P{k}_c", f"P{k}_p", f"z_{k}") for k in range(K)]
    state = parts.sample(inst, np.random.default_rng(1), inst.truth, 0.7)
    xa, xb = parts.lift(inst, state), plain.lift(inst, state)
    va, vb = a.variables, b.variables
    assert all(np.array_equal(xa[va.slice(n)], xb[vb.slice(n)]) for n in va.names if n != "h")
    assert xa @ (a.Q @ xa) == pytest.approx(xb @ (b.Q @ xb), rel=1e-14) and xa @ (a.Q @ xa) > 0
    assert parts.cost(inst, state) == pytest.approx(xa @ (a.Q @ xa), rel=1e-12)
    ca = {c.name: c.value(np.outer(xa, xa)) for c in a.primary()}
    cb = {c.name: c.value(np.outer(xb, xb)) for c in b.primary()}
    assert ca.keys() == cb.keys() and max(abs(ca[k] - cb[k]) for k in ca) <= 1e-12
    assert max(abs(v) for k, v in ca.items()) <= 1e-12  # a lifted sample meets every primary constraint
    assert parts.recover(inst, xa)["C"] == pytest.approx(state["C"], abs=1e-12)


@pytest.mark.parametrize("make, message", [
    (lambda: Variable("C", Rotation(2), element="P_{block}"), r"element must be a format of \{block\} and \{i\}"),
    (lambda: Variable("C", Rotation(2), element="{i}{block}"), r"giving identifiers"),
    (lambda: _chain_factors(roles=("h", "c", "p"))(_chain({"M": 3}, np.random.default_rng(0))),
     r"roles must name its factors' 6 blocks"),
])
def test_element_names_and_roles_that_cannot_be_used_are_one_line_errors(make, message):
    with pytest.raises(ProblemDefinitionError, match=message):
        out = make()
        if not isinstance(out, Variable):
            Graph(CHAIN, _chain({"M": 3}, np.random.default_rng(0)).truth, out)


# ----------------------------------------------------------------------------- cost-only variables and their costs


def _moving(params, rng):
    inst = _chain(params, rng)
    inst.truth["v"] = rng.standard_normal((params["M"], 2))
    inst.measurements["v0"] = rng.standard_normal(2)
    return inst


def _moving_factors(velocities: bool = True):
    """The chain with velocities v_k (cost-only): e = [w − v_k; v_k − v_{k+1}] couples the step's own block w with
    them; a prior on v_0; data kept off the model factors; named equations, paper rows and rotation constraints."""
    def factors(inst):
        K = len(inst.truth["C"])
        rotated = lambda C, D: np.einsum("rij,rj->ri", C.x, D)  # noqa: E731
        yield Family([(f"C{k}", f"p{k}") for k in range(K)], lambda C, p, z, D: z.z - p.x, data=inst.measurements["d"],
                     type="meas", auxiliary=Auxiliary({"z": 2}, value=lambda C, p, D: rotated(C, D),
                                                      equations=lambda C, p, z, D: z.z - rotated(C, D),
                                                      names=("z[x]", "z[y]")),
                     paper={"norm": lambda C, p, z, D: (z.z * z.z).sum(1) - (D * D).sum(1)},
                     names=[f"meas_{k}" for k in range(K)], aux_names=[str(k) for k in range(K)], record_data=False)
        if velocities:
            yield Factor("v0", lambda v: inst.measurements["v0"] - v.x, weight=4.0, name="prior")
        steps = [(f"C{k}", f"p{k}", f"C{k + 1}", f"p{k + 1}") for k in range(K - 1)]
        error = lambda C1, p1, C2, p2, v1, v2, w, D: np.hstack([w.w - v1.x, v1.x - v2.x])  # noqa: E731
        yield Family([s + (f"v{k}", f"v{k + 1}") for k, s in enumerate(steps)] if velocities else steps,
                     error if velocities else None, data=inst.measurements["u"], type="step",
                     weight=np.diag([1.0, 2.0, 3.0, 4.0]) if velocities else None,
                     auxiliary=Auxiliary({"w": 2}, value=lambda C1, p1, C2, p2, *rest: p2.x - p1.x - rest[-1],
                                         equations=lambda C1, p1, C2, p2, *rest: rest[-2].w - p2.x + p1.x + rest[-1]),
                     paper={"pair": lambda C1, p1, C2, p2, *rest: np.stack(
                         [((rest[-2].w - p2.x + p1.x + rest[-1]) * p.x).sum(1) for p in (p1, p2)], 1)},
                     paper_labels={"pair": ("p", "p'")}, names=[f"step_{k + 1}_{k}" for k in range(K - 1)],
                     aux_names=[f"{k + 1}_{k}" for k in range(K - 1)], roles=("h", "c", "p", "c'", "p'", "w"))
    return factors


MOVING = [Variable("C", Rotation(2), block="c", element="P{i}_{block}", factor="rot",
                   constraint_names=lambda equation, index, **_: f"orth(P{index}_c)[{equation[5:-1]}]"),
          Variable("p", Euclidean(2), element="P{i}_{block}"),
          Variable("v", Euclidean(2), element="{block}_{i}", cost_only=True)]


def test_cost_only_variables_are_last_in_no_factor_and_make_the_cost_explicit():
    """``Variable.cost_only``: the velocities' blocks come after the auxiliary blocks, no factor lists them, the
    costs on them make ``Model.cost`` (the factors touching them have none), which is every declared cost:
    xᵀQx is the derived cost at a lifted sample.  ``Auxiliary.names``, ``Family.paper_labels``,
    ``Family.record_data`` and ``Variable.constraint_names`` name and keep what they say."""
    K = 4
    inst = _moving({"M": K}, np.random.default_rng(0))
    parts = derive(MOVING, _moving_factors(), by_element=True)
    m = parts.build(inst)
    names = m.variables.names
    assert names[1 + 2 * K:] == [f"z_{k}" for k in range(K)] + [f"w_{k + 1}_{k}" for k in range(K - 1)] + \
        [f"v_{k}" for k in range(K)]
    assert [f.name for f in m.factors] == [n for k in range(K) for n in (f"rot_{k}", f"meas_{k}")] + \
        [f"step_{k + 1}_{k}" for k in range(K - 1)]
    assert not any(b.startswith("v_") for f in m.factors for b in f.blocks)
    step = m.factor("step_1_0")
    assert step.blocks == ("h", "P0_c", "P0_p", "P1_c", "P1_p", "w_1_0") and step.cost is None
    assert m.factor("meas_0").cost is not None and m.factor("meas_0").data is None
    assert [c.name for c in m.factor("meas_0").constraints] == ["meas_0:z[x]", "meas_0:z[y]"]
    assert [c.name for c in m.factor("rot_0").constraints] == [f"orth(P0_c)[{i}]" for i in ("0,0", "0,1", "1,1")]
    assert [c.name for c in m.paper["pair"][:2]] == ["step_1_0:pair[p]", "step_1_0:pair[p']"]
    assert m.cost is not None
    state = parts.sample(inst, np.random.default_rng(1), inst.truth, 0.7)
    x = parts.lift(inst, state)
    assert x @ (m.Q @ x) == pytest.approx(parts.cost(inst, state), rel=1e-12)
    assert max(abs(c.value(np.outer(x, x))) for c in m.all_constraints() if c.family != "homogenisation") <= 1e-12
    assert np.array_equal(parts.recover(inst, x)["v"], state["v"])
    # without the velocities: the steps have no residual (constraints only) and the cost is the factors'
    still = derive(MOVING[:2], _moving_factors(velocities=False), by_element=True).build(inst)
    assert still.cost is None and still.factor("step_1_0").cost is None
    assert [c.name for c in still.factor("step_1_0").constraints] == ["step_1_0:aux[0]", "step_1_0:aux[1]"]
    assert still.variables.names == names[:len(still.variables.names)]


def test_a_state_map_gives_the_layer_its_variables():
    """``derive(state=…)``: the instance's truth and the states the parts take hold the variables in the module's
    own form (here one stack of (C, p) pairs), mapped to the layer's."""
    inst = _chain({"M": 3}, np.random.default_rng(0))
    packed = {"pose": np.concatenate([inst.truth["C"], inst.truth["p"][:, :, None]], axis=2)}
    inst.truth = packed
    unpack = lambda s: {"C": s["pose"][:, :, :2], "p": s["pose"][:, :, 2]}  # noqa: E731
    chain = _chain_factors()
    parts = derive(CHAIN, lambda i: chain(types.SimpleNamespace(truth=unpack(i.truth), measurements=i.measurements)),
                   by_element=True, state=unpack)
    plain = derive(CHAIN, _chain_factors(), by_element=True)
    ref = _chain({"M": 3}, np.random.default_rng(0))
    assert np.array_equal(parts.lift(inst, packed), plain.lift(ref, ref.truth))
    assert parts.build(inst).variables.names == plain.build(ref).variables.names


@pytest.mark.parametrize("make, message", [
    (lambda: Variable("v", Euclidean(2), lifting={"n": lambda v: [v @ v]}, cost_only=True),
     r"a cost-only variable has no lifting"),
    (lambda: Variable("C", Rotation(2), cost_only=True),
     r"a cost-only variable has no lifting, no products and no manifold"),
    (lambda: Auxiliary({"z": 2}, value=lambda *a: None, equations=lambda *a: None, names=("",)),
     r"names must be non-empty strings"),
])
def test_cost_only_and_naming_declarations_that_cannot_be_used_are_one_line_errors(make, message):
    with pytest.raises(ProblemDefinitionError, match=message):
        make()


@pytest.mark.parametrize("edit, message", [
    ({"aux_names_count": True}, r"the auxiliary names 1 equations, its equations return 2"),
    ({"labels": ("p",)}, r"paper_labels gives 1 labels for the 2 rows of 'pair'"),
    ({"touch": True}, r"its equations or paper rows involve a cost-only variable"),
])
def test_names_and_cost_only_rows_that_do_not_fit_are_one_line_errors(edit, message):
    inst = _moving({"M": 3}, np.random.default_rng(0))

    def factors(inst):
        for f in _moving_factors()(inst):
            if isinstance(f, Family) and f.type == "meas" and "aux_names_count" in edit:
                f.auxiliary.names = ("z",)
            if isinstance(f, Family) and f.type == "step" and "labels" in edit:
                f.paper_labels = {"pair": edit["labels"]}
            if isinstance(f, Family) and f.type == "step" and "touch" in edit:
                f.paper["pair"] = lambda C1, p1, C2, p2, v1, v2, w, D: (w.w * v1.x).sum(1)
            yield f

    with pytest.raises(ProblemDefinitionError, match=message):
        Graph(MOVING, inst.truth, factors(inst), by_element=True).model()


def test_builds_share_the_probe_fits_and_still_check_each_instances_data(monkeypatch):
    """Two instances of pose averaging: the second build reuses the first one's probe fits (the same read-only
    arrays) and gives the model a fresh fit gives (cost, primary and paper matrices equal).  A stored fit that
    does not write a family's rows raises at the next build: each build's check against its data still runs."""
    from autotight.graph import family

    prob = load("pose_averaging")

    def build(seed):  # a new instance object each time: the layer keeps one graph per instance
        return prob.build(prob.generate(prob.parse_params({"M": 4}), seed))

    monkeypatch.setattr(family, "_PROBE_FITS", {})
    fresh = build(1)
    monkeypatch.setattr(family, "_PROBE_FITS", {})
    build(0)
    stored = dict(family._PROBE_FITS)
    assert len(stored) == 3  # the auxiliary's equations, R1 and R2
    assert all(not a.flags.writeable for fit in stored.values() for a in fit[1:])
    reused = build(1)
    assert family._PROBE_FITS.keys() == stored.keys()
    assert all(family._PROBE_FITS[k] is stored[k] for k in stored)
    assert abs(fresh.Q - reused.Q).max() == 0
    pairs = list(zip(fresh.primary() + fresh.paper_constraints(), reused.primary() + reused.paper_constraints()))
    assert len(pairs) > len(fresh.primary())
    for a, b in pairs:
        assert a.name == b.name and abs(a.A - b.A).max() == 0 and a.b == b.b
    for key, (k, mono, row, coef) in stored.items():
        family._PROBE_FITS[key] = (k, mono, row, coef * 2.0)
        with pytest.raises(ProblemDefinitionError, match="are not polynomials"):
            build(1)
        family._PROBE_FITS[key] = (k, mono, row, coef)
