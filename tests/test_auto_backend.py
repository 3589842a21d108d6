"""The default backend "auto": the SDP layer picks Clarabel or our IPM by the SDP's size."""

import numpy as np
import pytest

import autotight as at
from autotight import sdp
from autotight.limits import check_size
from autotight.sdp.config import AUTO_IPM_MIN_N, SolverConfig, SolverConfigError


def test_auto_resolves_by_size_and_explicit_choices_stay():
    assert SolverConfig().backend == "auto"
    assert SolverConfig().for_size(AUTO_IPM_MIN_N - 1).backend == "clarabel"
    assert SolverConfig().for_size(AUTO_IPM_MIN_N).backend == "ipm"
    for name in ("clarabel", "ipm"):
        assert SolverConfig(backend=name).for_size(10 ** 6).backend == name
        assert SolverConfig(backend=name).for_size(1).backend == name
    with pytest.raises(SolverConfigError):
        SolverConfig(backend="auto:x")


def test_small_model_solves_with_clarabel_as_before():
    prob = at.load_problem("rotation_averaging")
    inst = prob.generate({}, 0)
    model = prob.build(inst)
    auto = sdp.solve_model(model, model.primary(), SolverConfig(tol=1e-8))
    explicit = sdp.solve_model(model, model.primary(), SolverConfig(backend="clarabel", tol=1e-8))
    assert auto.solver == explicit.solver and auto.solver.startswith("clarabel")
    assert abs(auto.primal_cost - explicit.primal_cost) <= 1e-9 * max(1.0, abs(explicit.primal_cost))


def test_large_model_size_check_counts_a_sparse_x():
    # discrete trajectory K = 1000 has N ≈ 2.4e4: a dense X would need ~57 GB, the IPM's X is sparse (~1 GB)
    prob = at.load_problem("discrete_trajectory")
    est = check_size(prob, {"K": 1000}, SolverConfig())
    assert est is not None and est.N >= AUTO_IPM_MIN_N and not est.dense_x and est.bytes < 2e9
    assert est.bytes == check_size(prob, {"K": 1000}, SolverConfig(backend="ipm")).bytes


def test_effective_tol_of_an_unresolved_config_is_its_tol():
    assert sdp.effective_tol(SolverConfig(tol=1e-9)) == 1e-9
    assert np.isclose(sdp.effective_tol(SolverConfig(tol=1e-9).for_size(10 ** 5)), 1e-7)


def test_clarabel_kkt_solver_by_size_and_faer_agrees(monkeypatch):
    from autotight.sdp import clarabel_direct

    assert clarabel_direct.kkt_solver(clarabel_direct.FAER_MIN_N - 1) == "auto"
    assert clarabel_direct.kkt_solver(clarabel_direct.FAER_MIN_N) == "faer"
    prob = at.load_problem("rotation_averaging")
    model = prob.build(prob.generate({}, 0))
    config = SolverConfig(backend="clarabel", tol=1e-9)
    qdldl = sdp.solve_model(model, model.primary(), config)
    monkeypatch.setattr(clarabel_direct, "FAER_MIN_N", 1)
    faer = sdp.solve_model(model, model.primary(), config)
    assert qdldl.usable and faer.usable
    assert abs(faer.primal_cost - qdldl.primal_cost) <= 1e-7 * abs(qdldl.primal_cost)
