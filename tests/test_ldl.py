"""Sparse symmetric LDLᵀ without pivoting (autotight.ldl)."""

import numpy as np
import pytest
import scipy.sparse as sp

from autotight.ldl import SymmetricLDL


def test_symmetric_ldl_counts_inertia_and_reports_a_zero_pivot():
    """The pivots of a symmetric indefinite matrix have its eigenvalues' signs (Sylvester); a singular
    matrix whose elimination meets an exact zero pivot raises RuntimeError."""
    rng = np.random.default_rng(2)
    V = np.linalg.qr(rng.standard_normal((30, 30)))[0]
    eig = np.concatenate([-rng.uniform(1, 2, 7), rng.uniform(1, 2, 23)])
    A = sp.csc_array((V * eig) @ V.T)
    ldl = SymmetricLDL(A)
    assert np.count_nonzero(ldl.pivots < 0) == 7
    b = rng.standard_normal(30)
    assert np.linalg.norm(A @ ldl.solve(b) - b) <= 1e-10 * np.linalg.norm(b)
    with pytest.raises(RuntimeError):
        SymmetricLDL(sp.csc_array(np.ones((3, 3))))
