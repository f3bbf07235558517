import numpy as np
import pytest

from ccl_cli.errors import ConfigError
from ccl_cli.metrics import ncpe, ncpe_observed, nmse, npe, npoe, nppe, nupe

U = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
PI = np.array([[1.0, 1.0], [2.0, 0.0], [0.0, -1.0]])
N_TRUE = np.diag([1.0, 0.0])  # constraint on the second axis
N_EST = np.diag([0.0, 1.0])  # completely wrong


def var_sum(Y, ddof=1):
    return float(np.var(Y, axis=0, ddof=ddof).sum())


def test_nppe_by_hand():
    # Nπ = [[1,0],[2,0],[0,0]], Ñπ = [[0,1],[0,0],[0,-1]] → squared errors 2, 4, 1
    m = nppe(N_TRUE, N_EST, PI, U)
    assert m.error == pytest.approx(7 / 3)
    # var(U): dim0 [1,0,1] → 1/3, dim1 [0,2,1] → 1
    assert m.normaliser == pytest.approx(4 / 3)
    assert m.value == pytest.approx((7 / 3) / (4 / 3))
    assert m.normaliser_of == "u"


def test_nppe_original_normalisers():
    assert nppe(N_TRUE, N_EST, PI, U, convention="original").normaliser == pytest.approx(var_sum(PI))
    w = PI @ N_TRUE.T
    m = nppe(N_TRUE, N_EST, PI, U, convention="original", state_dependent=True)
    assert m.normaliser == pytest.approx(var_sum(w))
    with pytest.raises(ConfigError):
        nppe(N_TRUE, N_EST, PI, U, convention="matlab")


def test_npoe_by_hand():
    # u − Ñu with Ñ = diag(0,1): [[1,0],[0,0],[1,0]] → 1, 0, 1
    m = npoe(N_EST, U)
    assert m.error == pytest.approx(2 / 3)
    assert m.value == pytest.approx((2 / 3) / (4 / 3))
    stack = np.broadcast_to(N_EST, (3, 2, 2))
    assert npoe(stack, U).value == pytest.approx(m.value)


def test_npe_by_hand_and_ddof():
    W = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    # P̃u: [1,0], [0,2], [1,0]; minus w̃: [0,0], [0,1], [0,0] → 0, 1, 0
    m = npe(U, W)
    assert m.error == pytest.approx(1 / 3)
    assert m.normaliser == pytest.approx(4 / 3)
    assert npe(U, W, convention="original").normaliser == pytest.approx(var_sum(U, ddof=0))


def test_nupe_and_ncpe_by_hand():
    est = PI + np.array([[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    m = nupe(PI, est)
    assert m.error == pytest.approx(2 / 3)
    assert m.value == pytest.approx((2 / 3) / var_sum(PI))
    c = ncpe(N_TRUE, PI, est)
    # N(π − π̃) = [[0,0],[1,0],[0,0]] → 1/3; normaliser var(Nπ) = var([1,2,0]) = 1
    assert c.error == pytest.approx(1 / 3)
    assert c.normaliser == pytest.approx(1.0)


def test_nmse_per_dimension():
    Y = np.array([[0.0, 1.0], [2.0, 1.0], [4.0, 1.0]])
    est = Y + np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    out = nmse(Y, est)
    assert out[0] == pytest.approx(1.0 / 4.0)
    assert np.isnan(out[1])  # constant dimension has no variance


def test_ncpe_observed_and_named_nupe_by_hand():
    est = np.array([[1.0, 1.0], [0.0, 0.0], [2.0, 2.0]])
    # Ñπ̃ with Ñ = diag(0,1): [[0,1],[0,0],[0,2]]; u − Ñπ̃ = [[1,-1],[0,2],[1,-1]] → 2, 4, 2
    m = ncpe_observed(N_EST, U, est)
    assert m.name == "NCPE_obs" and m.error == pytest.approx(8 / 3)
    assert m.value == pytest.approx((8 / 3) / (4 / 3))
    w = nupe(PI, est, "NUPE_w", "w")
    assert (w.name, w.normaliser_of) == ("NUPE_w", "w")
    assert w.value == pytest.approx(nupe(PI, est).value)
