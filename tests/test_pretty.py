"""autotight.pretty: the polynomials that `discover` prints and saves, as exact strings.

Hand-built constraints on a vector lifting (d = 1) and a matrix lifting (d = 3): α·I blocks as
aᵀb, entry-wise terms with axis names, h·x as x and h² as a constant, coefficient formatting
(a coefficient that prints as 1 is left out, 4 significant digits, small entries dropped), the
sign "−" everywhere (also for a constant term alone and for the right-hand side), Greek names
with subscripts, and names that merely start like a Greek letter's (w_3 is not ϖ_3).
"""

from __future__ import annotations

import numpy as np
import pytest

from autotight.model import Variables
from autotight.model import QuadForm as Q
from autotight.pretty import polynomial, symbol

V1 = Variables([("c1", 3), ("phi_2", 1), ("rho_3_1", 3), ("x", 5)])
V3 = Variables([("c1", 1), ("c2", 1), ("w_3", 1), ("varpi_1", 1)], d=3)


def p1(q: Q, b: float = 0.0) -> str:
    return polynomial(q.matrix(), V1, b)


def p3(q: Q, b: float = 0.0) -> str:
    return polynomial(q.matrix(), V3, b)


def test_vector_lifting_identity_blocks_and_constants():
    assert p1(Q(V1).add("c1", "c1", 1.0).const(-1.0)) == "c1ᵀc1 − 1 = 0"
    assert p1(Q(V1).add("c1", "c1", -2.0).const(1.0)) == "−2 c1ᵀc1 + 1 = 0"
    assert p1(Q(V1).add("c1", "rho_3_1", 0.5)) == "0.5 c1ᵀρ_3_1 = 0"
    assert p1(Q(V1).add("c1", "rho_3_1", -1.0).add("c1", "c1", 1.0)) == "c1ᵀc1 − c1ᵀρ_3_1 = 0"


def test_vector_lifting_entrywise_terms_and_linear_terms():
    # h·x prints as x; a diagonal that is not α·I prints entry by entry with axis names
    assert p1(Q(V1).linear("phi_2", np.array([3.0])).add("c1", "c1", np.diag([1.0, 2.0, 3.0]))) == \
        "3 φ_2 + c1.x² + 2 c1.y² + 3 c1.z² = 0"
    # an off-diagonal entry of a diagonal block: both (x, y) and (y, x) are one term
    assert p1(Q(V1).add("c1", "c1", np.array([[0, 1.0, 0], [0, 0, 0], [0, 0, 0]]))) == "c1.x·c1.y = 0"
    # blocks longer than 3 are indexed by position
    assert p1(Q(V1).linear("x", np.array([0, 0, 0, 0, -1.0]))) == "−x.4 = 0"
    assert p1(Q(V1).add("phi_2", "x", np.array([[0, 0, 2.0, 0, 0]]))) == "2 φ_2·x.2 = 0"


def test_coefficient_formatting():
    # 4 significant digits; entries below 1e-10 of the largest are dropped
    assert p1(Q(V1).add("phi_2", "c1", np.array([[1 / 3, 0, -1e-12]]))) == "0.3333 c1.x·φ_2 = 0"
    # a coefficient that prints as 1 is left out, like an exact 1
    assert p1(Q(V1).add("c1", "c1", 1 + 1e-6).const(-1.0)) == "c1ᵀc1 − 1 = 0"
    assert p1(Q(V1).add("c1", "c1", 1.001).const(-1.0)) == "1.001 c1ᵀc1 − 1 = 0"
    assert p1(Q(V1).add("c1", "c1", 12345.0).const(-2e-5)) == "1.234e+04 c1ᵀc1 − 2e-05 = 0"


def test_sign_of_a_lone_constant_and_of_the_right_hand_side():
    assert p1(Q(V1).const(-2.5), 1.0) == "−2.5 = 1"
    assert p1(Q(V1).add("c1", "c1", 1.0), -1.0) == "c1ᵀc1 = −1"
    assert p1(Q(V1).add("c1", "c1", 1.0), 0.25) == "c1ᵀc1 = 0.25"
    assert polynomial(Q(V1).matrix(), V1, 0.0) == "0 = 0"


def test_matrix_lifting_d3():
    # ⟨A, ΘᵀΘ⟩ with h = I₃: −I/3 on the h block is the constant −1; c1² is c1ᵀc1 (columns of width 3)
    assert p3(Q(V3).add("c1", "c1", 1.0).add("h", "h", -np.eye(3) / 3)) == "c1² − 1 = 0"
    assert p3(Q(V3).add("c1", "c2", 1.0)) == "c1·c2 = 0"
    assert p3(Q(V3).add("c1", "c2", 1.0).add("c2", "c1", 1.0)) == "2 c1·c2 = 0"
    assert p3(Q(V3).add("h", "c1", np.array([[1.0], [0.0], [0.0]]))) == "h.x·c1 = 0"


def test_greek_names_need_the_whole_name_or_a_subscript():
    assert [symbol(n) for n in ("rho_3", "phi", "xi12", "varpi_1", "theta_k_2", "ell")] == \
        ["ρ_3", "φ", "ξ12", "ϖ_1", "θ_k_2", "ℓ"]
    # a block that only starts with w (or with a Greek name) is not Greek
    assert [symbol(n) for n in ("w_3", "w", "weight", "phil_2", "rhox", "c1", "T3_r", "p0_c1")] == \
        ["w_3", "w", "weight", "phil_2", "rhox", "c1", "T3_r", "p0_c1"]
    assert p3(Q(V3).add("w_3", "varpi_1", -2.0)) == "−2 w_3·ϖ_1 = 0"
    # one Latin letter before a Greek name is a prefix (robust pose averaging's u_m = ½(1 + w_m)ξ_m blocks)
    assert [symbol(n) for n in ("urho_2", "zphi_0", "uphi")] == ["uρ_2", "zφ_0", "uφ"]


@pytest.mark.parametrize("name", ["pose_averaging", "rotation_averaging"])
def test_primary_constraints_of_shipped_problems_print_as_expected(name):
    """The printed orthonormality constraints of a shipped problem: c_iᵀc_i − 1 and c_iᵀc_j."""
    from autotight.problem import load

    prob = load(name)
    model = prob.build(prob.generate({"M": 2}, 0))
    text = {polynomial(c.A, model.variables, c.b) for c in model.primary()}
    assert {"1 = 1", "c1ᵀc1 − 1 = 0", "c1ᵀc2 = 0", "c3ᵀc3 − 1 = 0"} <= text
