"""Reduction on a monotone toy oracle: irreducible result, solve counts, prefix rules agree."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from autotight.discovery.reduce import reduce_pairs, shortest_tight_prefix, shortest_tight_prefix_bisect


@dataclass
class _Res:
    y: np.ndarray | None


@dataclass
class _Verdict:
    tight: bool


@dataclass
class ToyOracle:
    """Tight iff the set covers every pair of ``needed`` (monotone); importance = a given weight."""

    needed: set
    weight: dict
    n_solves: int = 0
    log: list = field(default_factory=list)

    def solve(self, chosen, stage=""):
        self.n_solves += 1
        chosen = list(chosen)
        self.log.append((stage, len(chosen)))
        return _Verdict(self.needed <= set(chosen)), _Res(np.array([1.0]))

    def ok(self, v):
        return v.tight

    def importance(self, res, chosen):
        return {p: self.weight[p] for p in chosen}


def _toy(n: int, needed: list[int], seed: int = 0) -> tuple[ToyOracle, list]:
    rng = np.random.default_rng(seed)
    pairs = [("t", str(i)) for i in range(n)]
    w = {p: float(rng.uniform(1, 2)) if int(p[1]) in needed else float(rng.uniform(0, 1e-6)) for p in pairs}
    return ToyOracle({pairs[i] for i in needed}, w), pairs


def test_reduction_is_irreducible_without_verification_solves():
    oracle, pairs = _toy(200, [3, 50, 51, 120, 199])
    red = reduce_pairs(oracle, pairs, _Res(np.array([1.0])))
    assert set(red.pairs) == oracle.needed and red.irreducible and red.proof == "monotonicity"
    assert red.n_verify_solves == 0 and red.n_solves == oracle.n_solves
    # the negligible 195 pairs go in one block; each needed pair costs one failed single-pair solve
    assert oracle.log[0] == ("reduce", 5) and red.n_solves <= 1 + 2 * 5


def test_reduction_with_verification_matches_and_counts_its_solves():
    oracle, pairs = _toy(60, [0, 7, 8])
    red = reduce_pairs(oracle, pairs, _Res(np.array([1.0])), verify=True)
    assert set(red.pairs) == oracle.needed and red.proof == "verified" and not red.dropped_in_verification
    assert red.n_solves + red.n_verify_solves == oracle.n_solves


def test_prefix_by_bisection_equals_autotight_scan():
    oracle, pairs = _toy(300, [1, 2, 40, 41, 42, 250])
    lin, n_lin = shortest_tight_prefix(oracle, pairs, _Res(None))
    bis, n_bis = shortest_tight_prefix_bisect(oracle, pairs, _Res(None))
    assert lin == bis and set(bis) == oracle.needed
    assert n_lin == len(lin) + 1 and n_bis <= 2 + int(np.ceil(np.log2(300)))
