"""Per-backend options in ``SolverConfig``: ``ClarabelOptions`` (``config.clarabel``) and ``IpmOptions``
(``config.ipm``).

Each option object refuses a bad value when it is built (a one-line SolverConfigError naming the field);
the options reach the solver (Clarabel's settings, the IPM's search direction) and the retry policy; and
the solve paths they choose reach the same optimum.  Tolerances: Clarabel solves to relative gap 1e-9, so
its paths agree to 1e-7 relative; the IPM stops at 1e-7 (``schur_ipm.IPM_MIN_TOL``), so it is compared
to 1e-6 relative.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from autotight import sdp
from autotight.errors import AutotightError
from autotight.sdp import ClarabelOptions, IpmOptions, SolverConfig, SolverConfigError, schur_ipm
from autotight.sdp.clarabel_direct import ClarabelBackend, clarabel_settings


@pytest.mark.parametrize("make,field,allowed", [
    (lambda: ClarabelOptions(chordal="yes"), "ClarabelOptions.chordal", ("True", "False")),
    (lambda: ClarabelOptions(chordal=1), "ClarabelOptions.chordal", ("True", "False")),
    (lambda: ClarabelOptions(merge="greedy"), "ClarabelOptions.merge", ("'parent_child'", "'clique_graph'", "'none'")),
    (lambda: ClarabelOptions(regularization="tiny"), "ClarabelOptions.regularization", ("'small'", "'default'")),
    (lambda: IpmOptions(search="sd"), "IpmOptions.search", ("'nt'", "'hkm'")),
    (lambda: IpmOptions(step_fraction=1.0), "IpmOptions.step_fraction", ("(0, 1)",)),
    (lambda: IpmOptions(step_fraction="0.9"), "IpmOptions.step_fraction", ("(0, 1)",)),
])
def test_a_bad_option_is_a_one_line_error_naming_the_field_and_its_values(make, field, allowed):
    with pytest.raises(SolverConfigError) as e:
        make()
    msg = str(e.value)
    assert isinstance(e.value, AutotightError) and "\n" not in msg
    assert field in msg and all(a in msg for a in allowed), msg


def test_a_config_takes_only_option_objects():
    for kw in (dict(clarabel={"chordal": False}), dict(ipm="hkm"), dict(clarabel=IpmOptions())):
        with pytest.raises(SolverConfigError, match=f"{next(iter(kw))} must be a") as e:
            SolverConfig(**kw)
        assert "\n" not in str(e.value)


def test_the_defaults_are_the_documented_ones():
    c = SolverConfig()
    assert c.clarabel == ClarabelOptions(chordal=True, merge="parent_child", regularization="small")
    assert c.ipm == IpmOptions(search="nt", step_fraction=None)


def test_clarabel_options_reach_clarabels_settings():
    """The settings the backend builds (``clarabel_settings``) carry the options: merge method, chordal
    decomposition on or off, the small regularisation or Clarabel's own."""
    import clarabel

    own = clarabel.DefaultSettings()
    s = clarabel_settings(SolverConfig(), 50)
    assert s.chordal_decomposition_enable and s.chordal_decomposition_merge_method == "parent_child"
    assert s.static_regularization_constant == 1e-10 and not s.dynamic_regularization_enable
    s = clarabel_settings(SolverConfig(clarabel=ClarabelOptions(merge="clique_graph", regularization="default")), 50)
    assert s.chordal_decomposition_enable and s.chordal_decomposition_merge_method == "clique_graph"
    assert s.static_regularization_constant == own.static_regularization_constant
    assert s.dynamic_regularization_enable == own.dynamic_regularization_enable
    assert not clarabel_settings(SolverConfig(clarabel=ClarabelOptions(chordal=False)), 50).chordal_decomposition_enable
    # the clique path builds its cones itself: Clarabel's decomposition off whatever the options say
    assert not clarabel_settings(SolverConfig(), 50, chordal=False).chordal_decomposition_enable


def test_clarabels_retries_read_the_options():
    """Small regularisation → a retry with the default one; chordal, parent-child merging, one cone of at
    most ``RETRY_MAX_N`` columns → a retry with clique-graph merging; options that are already the
    retry's leave nothing to retry."""
    b = ClarabelBackend()
    cfg = SolverConfig(backend="clarabel")
    plan = b.retries(cfg, False, 20)
    assert [c.clarabel for _, c, _ in plan] == [ClarabelOptions(regularization="default"),
                                                 ClarabelOptions(merge="clique_graph")]
    assert all(replace(c, clarabel=cfg.clarabel) == cfg for _, c, _ in plan)  # only the options change
    assert [c.clarabel for _, c, _ in b.retries(cfg, True, 20)] == [ClarabelOptions(regularization="default")]
    done = replace(cfg, clarabel=ClarabelOptions(merge="clique_graph", regularization="default"))
    assert b.retries(done, False, 20) == []
    assert b.retries(replace(cfg, clarabel=ClarabelOptions(chordal=False, regularization="default")), False, 20) == []


def test_every_clarabel_option_solves_to_the_same_optimum(ra):
    """Rotation averaging, M = 4: one dense cone (chordal off), Clarabel's chordal decomposition with
    either merge method, and the default regularisation all reach the same optimal cost (1e-7 relative),
    each on the path the options name."""
    model = ra.build(ra.generate({"M": 4, "sigma": 0.1}, 0))
    cons = model.primary()
    runs = {name: sdp.solve(model.Q, cons, config=SolverConfig(backend="clarabel", clarabel=o)) for name, o in (
        ("chordal", ClarabelOptions()), ("dense", ClarabelOptions(chordal=False)),
        ("clique_graph", ClarabelOptions(merge="clique_graph")),
        ("default regularisation", ClarabelOptions(regularization="default")))}
    assert all(r.status == "Solved" for r in runs.values()), {k: r.status for k, r in runs.items()}
    assert runs["dense"].solver == "clarabel" and runs["chordal"].solver == "clarabel-chordal"
    f = runs["chordal"].primal_cost
    assert f > 0
    for name, r in runs.items():
        assert abs(r.primal_cost - f) <= 1e-7 * f, (name, r.primal_cost, f)


def _rotation_m4(ra):
    """Rotation averaging, M = 4 (σ = 0.1, seed 0): its model, primary constraints and Clarabel's optimal cost."""
    model = ra.build(ra.generate({"M": 4, "sigma": 0.1}, 0))
    cons = model.primary()
    return model, cons, sdp.solve(model.Q, cons, config=SolverConfig(backend="clarabel")).primal_cost


def test_the_ipm_search_direction_is_an_option_and_both_reach_clarabels_optimum(ra, monkeypatch):
    """Rotation averaging, M = 4, by our IPM with the Nesterov–Todd and the HKM direction: each reaches
    ``solve_blocks`` and both end Solved at Clarabel's optimum (1e-6 relative)."""
    model, cons, ref = _rotation_m4(ra)
    real, seen = schur_ipm.solve_blocks, []

    def recording(*a, **k):
        seen.append(k["search"])
        return real(*a, **k)

    monkeypatch.setattr(schur_ipm, "solve_blocks", recording)
    for s in ("nt", "hkm"):
        r = sdp.solve(model.Q, cons, config=SolverConfig(backend="ipm", ipm=IpmOptions(search=s)))
        assert seen[-1] == s and r.n_calls == 1  # solved by the IPM itself, not its Clarabel fallback
        assert r.status == "Solved" and r.solver == "autotight-ipm", r.message
        assert abs(r.primal_cost - ref) <= 1e-6 * ref


def test_a_stalled_ipm_solve_is_retried_with_the_fixed_step_fraction(ra, monkeypatch):
    """``IPMBackend.retries``: SDPT3's step lengths first; a solve that stalls is solved again with
    ``RETRY_STEP_FRACTION``, which reaches the ``solve_blocks`` loop, and that result is kept (Clarabel's
    optimum to 1e-6); a config that fixes the fraction itself gets no retry."""
    model, cons, ref = _rotation_m4(ra)
    real, seen = schur_ipm.solve_blocks, []

    def stalls_unless_fixed(*a, **k):
        seen.append(k["step_fraction"])
        res = real(*a, **k)
        if k["step_fraction"] is None:
            res.status = schur_ipm.Status.INSUFFICIENT_PROGRESS
        return res

    monkeypatch.setattr(schur_ipm, "solve_blocks", stalls_unless_fixed)
    r = sdp.solve(model.Q, cons, config=SolverConfig(backend="ipm"))
    assert seen == [None, schur_ipm.RETRY_STEP_FRACTION] and r.n_calls == 2
    assert r.solver == "autotight-ipm" and r.usable and "retried with the fixed step fraction" in r.message
    assert abs(r.primal_cost - ref) <= 1e-6 * ref
    fixed = SolverConfig(backend="ipm", ipm=IpmOptions(step_fraction=0.8))
    assert schur_ipm.IPMBackend().retries(fixed, True, 50) == []
    assert schur_ipm.IPMBackend().retries(SolverConfig(backend="ipm"), True, schur_ipm.RETRY_MAX_N + 1) == []
