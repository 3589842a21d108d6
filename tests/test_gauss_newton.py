"""autotight.gauss_newton: the local solver behind every shipped problem.

- Linear least squares (known minimiser by the normal equations): one Gauss-Newton step reaches it,
  with dense and with sparse J, W.
- Rosenbrock as a residual (minimiser (1, 1), cost 0) from the classic start (−1.2, 1).
- LM damping: e = atan(x) from x₀ = 3, where the undamped step overshoots to a higher cost; the
  damped step is accepted with a lower cost, and the solver reaches 0.
- Iteration count, ``converged`` and message on max_iter, and on a start that is already optimal.
- On SO(3) with the Cayley retraction: the Jacobian it is given (lie.residual_so3) against central
  differences, and convergence to the known minimiser of a symmetric pair of measurements.
- A bug in ``linearize`` raises; it is not read as "no decrease possible".
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from autotight import lie
from autotight.gauss_newton import gauss_newton


def _linear_problem(rng: np.random.Generator, sparse: bool = False):
    A = rng.standard_normal((12, 4))
    b = rng.standard_normal(12)
    w = rng.uniform(0.5, 2.0, 12)
    W = sp.diags(w, format="csr") if sparse else np.diag(w)
    x_star = np.linalg.solve(A.T @ (w[:, None] * A), A.T @ (w * b))
    J = sp.csr_array(A) if sparse else A

    def linearize(x):
        return A @ x - b, J, W

    return linearize, x_star, float((A @ x_star - b) @ (w * (A @ x_star - b)))


@pytest.mark.parametrize("sparse", [False, True])
def test_linear_least_squares_reaches_the_normal_equations_solution(sparse):
    linearize, x_star, f_star = _linear_problem(np.random.default_rng(0), sparse)
    res = gauss_newton(linearize, lambda x, eps: x + eps, np.zeros(4))
    np.testing.assert_allclose(res.state, x_star, rtol=0, atol=1e-12)
    assert res.cost == pytest.approx(f_star, rel=1e-12)
    # the first step is exact; the second finds no further decrease
    assert res.converged and res.message == "converged" and res.iterations == 2
    assert res.time_s >= 0


def test_rosenbrock_from_the_classic_start():
    def linearize(p):
        x, y = p
        return np.array([10 * (y - x * x), 1 - x]), np.array([[-20 * x, 10.0], [-1.0, 0.0]]), np.eye(2)

    res = gauss_newton(linearize, lambda p, eps: p + eps, np.array([-1.2, 1.0]))
    np.testing.assert_allclose(res.state, [1.0, 1.0], atol=1e-8)
    assert res.cost < 1e-20 and res.converged
    assert 2 <= res.iterations < 50


def _atan(x):
    return np.arctan(x), np.array([[1.0 / (1.0 + x[0] ** 2)]]), np.eye(1)


def test_damping_rejects_the_overshooting_step_and_the_cost_never_increases():
    x0 = np.array([3.0])
    f0 = np.arctan(3.0) ** 2
    # the undamped Gauss-Newton step overshoots to a higher cost ...
    e, J, _ = _atan(x0)
    x_gn = x0 - e / J[0, 0]
    assert x_gn[0] == pytest.approx(3.0 - np.arctan(3.0) * 10.0)
    assert np.arctan(x_gn[0]) ** 2 > f0
    # ... so the one allowed iteration must have grown λ until the cost went down
    one = gauss_newton(_atan, lambda x, eps: x + eps, x0, max_iter=1)
    assert one.iterations == 1 and not one.converged and one.message == "max_iter reached"
    assert one.cost < f0 and 0 < one.state[0] < 3.0
    # and the full run reaches the minimiser, its cost decreasing at every iteration
    costs = [gauss_newton(_atan, lambda x, eps: x + eps, x0, max_iter=k).cost for k in range(1, 8)]
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    res = gauss_newton(_atan, lambda x, eps: x + eps, x0)
    assert abs(res.state[0]) < 1e-8 and res.converged


def test_an_optimal_start_stops_at_once():
    res = gauss_newton(_atan, lambda x, eps: x + eps, np.array([0.0]))
    assert res.state[0] == 0.0 and res.cost == 0.0
    assert res.converged and res.iterations == 1


def test_rotation_jacobian_and_minimiser_on_so3():
    rng = np.random.default_rng(4)
    C_star = lie.random_rotation(rng)
    a = np.array([0.3, -0.2, 0.1])
    meas = [lie.cay(a) @ C_star, lie.cay(-a) @ C_star]  # symmetric about C_star

    def linearize(C):
        es, Js = zip(*(lie.residual_so3(C, Cm) for Cm in meas))
        return np.concatenate(es), np.vstack(Js), np.eye(6)

    def retract(C, psi):
        return lie.cay(psi) @ C

    # the Jacobian w.r.t. ψ in C ← cay(ψ^∧) C, by central differences
    C0 = lie.cay(np.array([0.4, 0.5, -0.3])) @ C_star
    _, J, _ = linearize(C0)
    h = 1e-6
    num = np.column_stack([(linearize(retract(C0, h * d))[0] - linearize(retract(C0, -h * d))[0]) / (2 * h)
                           for d in np.eye(3)])
    np.testing.assert_allclose(J, num, atol=1e-8)

    res = gauss_newton(linearize, retract, C0)
    assert res.converged
    # the stop is on the relative cost decrease (1e-12); near the minimiser a state error δ changes
    # the cost by O(δ²), so the cost is exact to ~1e-12 and the state to ~1e-6
    assert res.cost == pytest.approx(2 * float(a @ a), rel=1e-11)
    np.testing.assert_allclose(res.state, C_star, atol=1e-6)
    e, J, W = linearize(res.state)
    assert np.linalg.norm(J.T @ W @ e) < 1e-6


def test_a_bug_in_linearize_raises():
    calls = []

    def linearize(x):
        calls.append(1)
        if len(calls) > 1:  # a shape bug that shows up on the trial point
            return np.ones(3) @ np.ones(4), None, None
        return np.array([1.0]), np.eye(1), np.eye(1)

    with pytest.raises(ValueError):
        gauss_newton(linearize, lambda x, eps: x + eps, np.array([0.0]))


@pytest.mark.parametrize("chain", [True, False])
def test_block_jacobian_normal_equations_equal_the_sparse_products(chain):
    """``BlockJacobian.normal`` gives JᵀWJ (as a band on a chain of blocks, as a sparse matrix when the blocks
    couple far-apart columns), JᵀWe and diag(JᵀWJ) equal to the sparse products, and Gauss-Newton on a linear
    problem in block form reaches the normal equations' solution in one step."""
    from autotight.gauss_newton import BlockJacobian, BlockPattern, lower_band

    rng = np.random.default_rng(4)
    C, d, e = 40, 3, 2
    brow = np.concatenate([np.arange(C), C + np.arange(C - 1), C + np.arange(C - 1)])
    far = np.arange(1, C) if chain else (np.arange(C - 1) + C // 2) % C  # a chain, or pairs across the graph
    bcol = np.concatenate([np.arange(C), np.arange(C - 1), far])
    pattern = BlockPattern(brow, bcol, d, e, ((2 * C - 1) * d, C * e))
    assert pattern.banded == chain
    blocks = rng.standard_normal((brow.size, d, e))
    Wb = rng.standard_normal((2 * C - 1, d, d))
    Wb = Wb @ np.swapaxes(Wb, 1, 2) + d * np.eye(d)
    J = BlockJacobian(pattern, blocks, Wb)
    Js = J.matrix()
    W = sp.block_diag(list(Wb), format="csr")
    r = rng.standard_normal(Js.shape[0])
    H_ref = (Js.T @ W @ Js).toarray()
    H, ab, g, diag = J.normal(r)
    scale = np.abs(H_ref).max()
    if chain:
        assert H is None
        assert np.abs(ab - lower_band(sp.csr_array(H_ref), pattern.b)).max() <= 1e-13 * scale
    else:
        assert ab is None and np.abs(H.toarray() - H_ref).max() <= 1e-13 * scale
    assert np.abs(g - Js.T @ (W @ r)).max() <= 1e-13 * np.abs(g).max()
    assert np.abs(diag - np.diag(H_ref)).max() <= 1e-13 * scale
    x_star = np.linalg.solve(H_ref, Js.T @ (W @ r))
    res = gauss_newton(lambda x: (Js @ x - r, J, W), lambda x, eps: x + eps, np.zeros(C * e))
    assert np.abs(res.state - x_star).max() <= 1e-9 * np.abs(x_star).max()
