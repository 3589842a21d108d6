"""Carry-over of a discovered set reports, per factor type, what it expected and what it instantiated."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from autotight.discovery import DiscoveredSet, instantiate, learn
from autotight.discovery.catalog import carry_over
from autotight.errors import LearningError
from autotight.problem import load

# Three factors of type "t" on (h, x_m).  On factor m, x_m = c_m·h unless m is the "generic" one, whose
# x_m is sampled freely: a constant factor has the relations h·x = c h² and x·x = c² h², a generic one
# has none.  Learned where every factor is constant, the set loses both identities on a generic factor.
TOY = '''
import numpy as np
from autotight.model import Factor, Model, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Param
NAME = "carry_toy"
DESCRIPTION = "toy"
PARAMS = {"generic": Param(-1, "index of the factor sampled freely (-1: none)")}
M = 3
def generate(p, rng):
    c = np.array([0.5, -1.5, 2.0])
    return Instance(NAME, dict(p), {"c": c}, {"x": c.copy()})
def build(inst):
    V = Variables([(f"x{m}", 1) for m in range(M)])
    fs = [Factor(f"f{m}", "t", ("h", f"x{m}"), cost=QuadForm(V).add(f"x{m}", f"x{m}", 1.0).matrix(),
                 roles=("h", "x")) for m in range(M)]
    return Model(V, fs)
def lift(inst, s): return np.concatenate([[1.0], s["x"]])
def sample(inst, rng, nominal, spread):
    x = inst.measurements["c"].copy()
    g = inst.params["generic"]
    if g >= 0:
        x[g] = rng.standard_normal()
    return {"x": x}
def cost(inst, s): return float(s["x"] @ s["x"])
def local_solve(inst, init): return LocalResult(init, cost(inst, init), 0, True)
def recover(inst, T): return {"x": T.ravel()[1:]}
def random_state(inst, rng): return sample(inst, rng, inst.truth, 1.0)
def errors(inst, s): return {}
'''


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> object:
    p = Path(tmp_path_factory.mktemp("carry")) / "carry_toy.py"
    p.write_text(textwrap.dedent(TOY))
    return load(str(p))


def _pairs(prob) -> list[tuple[str, str]]:
    inst = prob.generate({"generic": -1}, 0)
    cat = learn(prob, inst, prob.build(inst), np.random.default_rng(0))
    return sorted(cat.by_pair())


def test_the_set_instantiates_fully_where_every_factor_has_it(toy):
    pairs = _pairs(toy)
    assert pairs == [("t", "h·x"), ("t", "x·x")]
    inst = toy.generate({"generic": -1}, 1)
    co = carry_over(toy, inst, pairs, np.random.default_rng(1))
    assert co.counts == {"t": (6, 6)} and not co.shortfall() and not co.issues
    assert len(co.constraints) == 6


def test_a_lost_identity_names_the_factor_type_and_counts(toy):
    pairs = _pairs(toy)
    inst = toy.generate({"generic": 2}, 1)
    with pytest.raises(LearningError, match=r"factor type 't': 4 of 6 expected constraints instantiated"):
        instantiate(toy, inst, pairs, np.random.default_rng(2))
    ds = DiscoveredSet(toy.name, {"generic": -1}, 0, pairs)
    with pytest.raises(LearningError, match=r"factor type 't': 4 of 6 .*not found on 1 of 3 groups \(f2\)"):
        ds.instantiate(toy, inst, np.random.default_rng(2))
    # opting out returns what carried over and says what did not
    cons, issues = instantiate(toy, inst, pairs, np.random.default_rng(2), strict=False)
    assert len(cons) == 4 and {c.factor for c in cons} == {"f0", "f1"}
    assert any("4 of 6" in i for i in issues) and sum("not found on 1 of 3" in i for i in issues) == 2
    assert len(ds.instantiate(toy, inst, np.random.default_rng(2), strict=False)) == 4


def test_spanning_index_finds_exactly_the_matrices_inside_a_groups_columns():
    """``SpanningIndex.within(cols)`` equals a scan of every matrix (random supports on 60 columns,
    unsorted group columns as factors give them), each once."""
    import scipy.sparse as sp

    from autotight.discovery.learn import SpanningIndex

    rng = np.random.default_rng(0)
    N = 60
    mats = []
    for _ in range(300):
        k = int(rng.integers(1, 5))
        r, c = rng.integers(0, N, k), rng.integers(0, N, k)
        mats.append(sp.coo_array((rng.standard_normal(k), (r, c)), shape=(N, N)))
    index = SpanningIndex(mats)
    for _ in range(50):
        cols = rng.permutation(N)[: int(rng.integers(3, 20))]
        inside = set(cols.tolist())
        want = [id(U) for U in mats if set(U.row.tolist()) | set(U.col.tolist()) <= inside]
        got = [id(U) for U in index.within(cols)]
        assert sorted(got) == sorted(want) and len(got) == len(set(got))
