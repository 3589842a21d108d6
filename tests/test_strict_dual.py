"""The strict dual (autotight.strict_dual) and the face of the bounded columns (autotight.face)."""

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from autotight.certificate import certificate, stack
from autotight.constraint_set import named as constraint_set
from autotight.face import free_columns
from autotight.pipeline import solve_instance
from autotight.problem import load
from autotight.sdp import solve_model
from autotight.model import Constraint
from autotight.strict_dual import bounded_shift, psd_by_inertia, strict_dual
from autotight.tightness import Criteria

MODULE = str(Path(__file__).parent / "free_columns_module.py")


def _rank_one_psd(n: int, rng: np.random.Generator, gap: float = 1.0):
    """(H, x): H ⪰ 0 with H x = 0 (x[0] = 1) and every other eigenvalue ≥ gap."""
    x = np.concatenate([[1.0], rng.standard_normal(n - 1)])
    B = rng.standard_normal((n, n))
    P = np.eye(n) - np.outer(x, x) / (x @ x)
    H = P @ (B @ B.T + gap * np.eye(n)) @ P
    return (H + H.T) / 2, x


def test_inertia_proves_psd_and_refutes_an_indefinite_matrix():
    rng = np.random.default_rng(0)
    H, x = _rank_one_psd(30, rng)
    ok, low, _ = psd_by_inertia(sp.csc_array(H + 1e-6 * np.eye(30)))
    assert ok and low > 0
    # a negative eigenvalue of −1e-8 relative to max|H| (along H's null vector) is found
    v = x / np.linalg.norm(x)
    bad = H + 1e-6 * np.eye(30) - (1e-6 + 1e-8 * np.abs(H).max()) * np.outer(v, v)
    assert np.linalg.eigvalsh(bad)[0] < 0
    ok, _, why = psd_by_inertia(sp.csc_array(bad))
    assert not ok and why


def test_strict_dual_lifts_the_null_direction_by_the_h_shift():
    """H with a negative eigenvalue −ε along x̂ (x̂_h = 1): δ ≈ ε·‖x̂‖² makes H + δ e₀e₀ᵀ ⪰ 0, and the δ
    found is within a factor GROWTH·2 of that while λ_min(H + δ e₀e₀ᵀ) ≥ 0 holds in exact arithmetic."""
    rng = np.random.default_rng(1)
    H, x = _rank_one_psd(40, rng)
    eps = 1e-7
    u = x / np.linalg.norm(x)
    Hm = H - eps * np.outer(u, u)
    E = sp.csc_array(([1.0], ([0], [0])), shape=H.shape)
    sd = strict_dual(sp.csc_array(Hm), E, x)
    assert sd.ok
    assert np.linalg.eigvalsh(Hm + sd.delta * np.diag(np.eye(40)[0]))[0] >= -1e-12
    assert eps * (x @ x) * 0.5 <= sd.delta <= 20 * eps * (x @ x) + 1e-6
    # a direction without an h component cannot be lifted: no δ proves anything
    w = rng.standard_normal(40)
    w[0] = 0.0
    assert not strict_dual(sp.csc_array(H - (w @ H @ w + 1e-3) * np.outer(w, w)), E, x).ok


def test_strict_dual_certifies_where_the_trace_bound_is_loose():
    """Pose averaging, paper set: the SDP's y with its h² multiplier raised by 1e-6·f(x̂) (H indefinite
    along x̂) and a loose (valid) trace bound T = 1e20, as continuous time's: the strict dual certifies
    with a bound of the order of the perturbation, where T gives nothing."""
    p = load("pose_averaging")
    inst = p.generate({"M": 10, "sigma": 0.01}, seed=0)
    model = p.build(inst)
    cons = constraint_set(model, "paper")
    res = solve_model(model, cons)
    loc = p.local_solve(inst, inst.truth)
    x = np.ravel(p.lift(inst, loc.state))
    base = certificate(model.Q, cons, res.y, x)
    assert base.certified
    y = np.array(res.y, dtype=float)
    i = next(k for k, c in enumerate(cons) if c.family == "homogenisation")
    y[i] += 1e-6 * abs(loc.cost)  # bᵀy above f(x̂) and H indefinite along x̂: the shift δ must undo it
    c = certificate(model.Q, cons, y, x, trace=1e20, tol=1e-5)
    assert c.lambda_min < 0
    assert c.certified and c.argument == "strict dual", c
    assert 1e-6 * abs(loc.cost) <= c.delta + (c.cost - c.dual_value) <= 1e-5 * abs(loc.cost)
    assert c.bound <= 1e-5 * abs(loc.cost)


def test_bounded_shift_lifts_null_directions_without_an_h_part():
    """H = diag(0, 0, 1, 1) on [h, a, b, c]: its null direction e_a has no h part, so the strict dual fails;
    lifting the group {h, a} (trace ≤ 1 each) proves H + δ·E_S ⪰ 0 at a loss δ·T_S of 2δ.  With a unbounded
    (group −1) nothing lifts e_a and the shift fails."""
    H = sp.csc_array(np.diag([0.0, 0.0, 1.0, 1.0]) - 1e-9 * np.diag([1.0, 1.0, 0.0, 0.0]))
    x = np.array([1.0, 0.0, 0.0, 0.0])
    E = sp.csc_array(([1.0], ([0], [0])), shape=(4, 4))
    assert not strict_dual(H, E, x, delta_max=1.0).ok
    bs = bounded_shift(H, np.array([0, 1, 2, 2]), [1.0, 1.0, 5.0], x, loss_max=1.0)
    assert bs.ok and list(bs.columns) == [0, 1] and bs.trace == 2.0
    assert np.linalg.eigvalsh(H.toarray() + bs.delta * np.diag([1.0, 1.0, 0.0, 0.0]))[0] > 0
    assert bs.loss == pytest.approx(2 * bs.delta) and 1e-9 < bs.delta < 1e-6
    assert not bounded_shift(H, np.array([0, -1, 1, 1]), [1.0, 5.0], x, loss_max=1.0).ok


def test_certificate_by_bounded_shift_where_the_optimum_is_not_unique():
    """min a² + b² + z² s.t. h² = 1, a² + b² = h², z² = M·h² (M = 1e12): every point of the circle is optimal,
    so H(y) has e_b in its null space besides x̂ = (1, 1, 0, √M).  Multipliers off by ε = 1e-5 on the circle's
    relation make H indefinite along e_a, e_b: the strict dual cannot lift them (no h part) and the trace bound
    (≥ M) times ε exceeds the tolerance; the bounded shift lifts h, a, b (trace ≤ 1 + 1) and certifies."""
    M, eps = 1e12, 1e-5
    diag = lambda *v: sp.coo_array(np.diag(v))  # noqa: E731
    cons = [Constraint(diag(1.0, 0, 0, 0), 1.0, name="h²", family="homogenisation"),
            Constraint(diag(-1.0, 1, 1, 0), 0.0, name="circle"), Constraint(diag(-M, 0, 0, 1), 0.0, name="z")]
    Q = sp.csr_array(np.diag([0.0, 1, 1, 1]))
    x = np.array([1.0, 1.0, 0.0, np.sqrt(M)])
    y = np.array([1.0 + M, 1.0 + eps, 1.0])
    c = certificate(Q, cons, y, x, tol=1e-6)
    assert c.lambda_min < 0
    assert c.certified and c.argument == "bounded shift", c
    assert c.bound <= 1e-9 * (1 + M)  # the loss δ·T_S with T_S = 3 (h, and a, b) and δ ≈ ε
    # p* = 1 + M exactly: the bound claims no more than that
    assert c.dual_value - c.delta * 3 <= 1 + M


def test_free_columns_are_the_product_block():
    """The bearing module: w_j,x (= u_j r_x) appears squared in no primary relation and not in the cost; with
    the primary set the fixed point also sets aside w_j,y (its only diagonal entries would be learned)."""
    p = load(MODULE)
    inst = p.generate({"J": 4}, seed=0)
    model = p.build(inst)
    face = free_columns(model.Q, stack(model.primary())[0])
    names = {model.variables.block_of(int(j))[0] for j in face.free}
    assert names == {f"w_{j}" for j in range(4)}
    assert face.free.size == 8 and face.touching.size == 8


@pytest.mark.parametrize("prior_sigma, tight", [(0.3, True), (10.0, False)])
def test_cost_acceptance_on_the_face(prior_sigma, tight):
    """accept='cost' with free columns: a tight face is certified (columns set aside, named in the
    certificate), a loose one (weak prior: relative gap ≈ 0.1) is not, and its reason names the blocks."""
    p = load(MODULE)
    inst = p.generate({"J": 4, "sigma": 0.01, "prior_sigma": prior_sigma}, seed=0)
    r = solve_instance(p, inst, "primary", criteria=Criteria(accept="cost"))
    assert r.certificate is not None and r.certificate.recession > 0
    if tight:
        assert r.tight and r.certificate.certified and r.certificate.rel_bound <= 1e-5
        assert abs(r.upper - r.local.from_truth.cost) <= 1e-6 * r.upper
    else:
        assert not r.tight and not r.certificate.certified
        assert r.verdict.rel_gap > 1e-2
        assert "w_*" in r.verdict.reason


def test_discover_accepts_cost_tight_with_free_columns(capsys):
    """`discover --accept cost` on the bearing module (free product columns w_j,x): cost-tight and
    certified on the training instance, and on ≥ 90 % of the held-out instances."""
    from autotight.cli import main
    import json

    assert main(["discover", MODULE, "--accept", "cost", "--no-progress", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["tight"] is True and rec["accept"] == "cost" and rec["validated"] is True
    held = rec["points"][0]["heldout"]
    assert held["instances"] >= 10 and held["fraction"] >= 0.9


def test_an_infeasible_candidate_is_never_certified():
    """x̂ moved off the constraints by 1e-4 (relative): whatever y proves about the relaxation, it is not
    a statement about x̂, so nothing is certified and the message names a violated constraint."""
    p = load("pose_averaging")
    inst = p.generate({"M": 5, "sigma": 0.01}, seed=0)
    model = p.build(inst)
    cons = constraint_set(model, "paper")
    res = solve_model(model, cons)
    x = np.ravel(p.lift(inst, p.local_solve(inst, inst.truth).state))
    assert certificate(model.Q, cons, res.y, x).certified
    bad = x + 1e-4 * np.linalg.norm(x) * np.random.default_rng(0).standard_normal(x.size) / np.sqrt(x.size)
    bad[0] = 1.0
    c = certificate(model.Q, cons, res.y, bad)
    assert not c.certified and "violates constraint" in c.message


@pytest.mark.slow
@pytest.mark.parametrize("sigma, seed", [(0.1, 0), (0.001, 0)])
def test_continuous_time_k21_is_certified(sigma, seed):
    """Continuous time at the paper's K = 21: the trace bound is ~1e15–1e24 against tr X̂ ≈ 90, so only
    an argument without a trace certifies; the bound is then below 1e-6 of the cost."""
    p = load("continuous_trajectory")
    r = solve_instance(p, p.generate({"K": 21, "sigma": sigma}, seed=seed))
    c = r.certificate
    assert r.tight and c.certified and c.rel_bound <= 1e-6
    assert c.argument in ("strict dual", "H ⪰ 0 (LDLᵀ inertia)")
    assert c.trace is None or c.trace > 1e6 * float(np.sum(np.asarray(p.lift(r.instance, r.local.best.state)) ** 2))
