import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError


def test_split_is_by_demonstration_and_seeded():
    data = sim.toy2d(n_demos=20, seed=0)
    train, test = data.split(0.3, seed=4)
    again_train, _ = data.split(0.3, seed=4)
    assert set(train.demo_ids).isdisjoint(test.demo_ids)
    assert len(test.demo_ids) == round(0.3 * data.n_demos)
    assert train.n_samples + test.n_samples == data.n_samples
    np.testing.assert_array_equal(train.X, again_train.X)
    other, _ = data.split(0.3, seed=5)
    assert set(other.demo_ids) != set(train.demo_ids)
    np.testing.assert_array_equal(test.truth["A"], data.truth["A"][np.isin(data.demo, test.demo_ids)])


def test_single_demonstration_splits_by_time():
    d = Demonstrations(X=np.arange(10.0)[:, None], U=np.ones((10, 1)))
    train, test = d.split(0.3)
    assert train.X[:, 0].tolist() == list(range(7)) and test.X[:, 0].tolist() == [7, 8, 9]


def test_concatenate_renumbers_and_broadcasts_constant_truth():
    a = Demonstrations(X=np.zeros((3, 2)), U=np.ones((3, 2)), demo=[5, 5, 6],
                       truth={"N": np.eye(2)})
    b = Demonstrations(X=np.ones((2, 2)), U=np.ones((2, 2)), demo=[5, 5],
                       truth={"N": np.zeros((2, 2))})
    both = Demonstrations.concatenate([a, b])
    assert both.demo.tolist() == [0, 0, 1, 2, 2]
    assert both.truth["N"].shape == (5, 2, 2)
    np.testing.assert_array_equal(both.true_projection()[3], np.zeros((2, 2)))


def test_shape_and_value_checks():
    with pytest.raises(InputError, match="X has 3 samples but U has 2"):
        Demonstrations(X=np.zeros((3, 2)), U=np.zeros((2, 2)))
    with pytest.raises(InputError, match="unknown ground-truth key"):
        Demonstrations(X=np.zeros((2, 1)), U=np.zeros((2, 1)), truth={"policy": np.zeros((2, 1))})
    d = Demonstrations(X=np.array([[0.0], [np.nan]]), U=np.zeros((2, 1)))
    with pytest.raises(InputError, match="X has 1 non-finite samples \\(first at row 1\\)"):
        d.check_finite()
    big = Demonstrations(X=np.zeros((3, 2)), U=np.array([[0.0, 1.0], [0.0, -3e216], [1e151, 0.0]]),
                         action_names=["ux", "uy"])
    with pytest.raises(InputError, match=r"U has 2 samples beyond ±1e\+150 \(first at row 1, uy = -3e\+216\)"
                       ):
        big.check_finite()  # squares overflow float64
    Demonstrations(X=np.full((2, 1), 1e150), U=np.full((2, 1), -1e150)).check_finite()  # at the bound: kept
    with pytest.raises(InputError, match="test fraction"):
        d.split(1.5)
