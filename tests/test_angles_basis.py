import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ccl_cli.learn.angles import angles_of, frame, unit_vector, unit_vector_jacobian
from ccl_cli.learn.basis import (
    LinearBasis,
    RBFBasis,
    default_sigma2,
    grid_centres,
    kmeans_centres,
)


@settings(max_examples=30, deadline=None)
@given(d=st.integers(2, 7), seed=st.integers(0, 10_000))
def test_unit_vector_jacobian_matches_finite_differences(d, seed):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-3, 3, (4, d - 1))
    a, J = unit_vector_jacobian(theta)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-12)
    eps = 1e-6
    for k in range(d - 1):
        step = np.zeros(d - 1)
        step[k] = eps
        fd = (unit_vector(theta + step) - unit_vector(theta - step)) / (2 * eps)
        np.testing.assert_allclose(J[:, :, k], fd, atol=1e-7)


@settings(max_examples=30, deadline=None)
@given(d=st.integers(2, 7), seed=st.integers(0, 10_000))
def test_angles_round_trip_and_frame_is_rotation(d, seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(5, d))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    np.testing.assert_allclose(unit_vector(angles_of(a)), a, atol=1e-12)
    R = frame(angles_of(a))
    np.testing.assert_allclose(R[:, :, 0], a, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(d), R.shape),
                               atol=1e-12)


def test_hyperspherical_formula_by_hand():
    theta = np.array([[np.pi / 3, np.pi / 4]])
    expected = [0.5, np.sin(np.pi / 3) * np.cos(np.pi / 4), np.sin(np.pi / 3) * np.sin(np.pi / 4)]
    np.testing.assert_allclose(unit_vector(theta)[0], expected)


def test_rbf_rows_sum_to_one_and_far_points_are_finite():
    X = np.random.default_rng(0).uniform(-1, 1, (200, 2))
    basis = RBFBasis(16, "kmeans", seed=0).fit(X)
    B = basis.transform(np.vstack([X, [[1e6, -1e6]], [[1e3, 0.0]]]))
    assert np.isfinite(B).all()
    np.testing.assert_allclose(B.sum(1), 1.0)
    # a far point is wholly given to its nearest centre
    far = np.array([[1e6, -1e6]])
    nearest = np.argmin(((basis.centres_ - far) ** 2).sum(1))
    assert basis.transform(far)[0, nearest] == 1.0


def test_rbf_values_by_hand():
    basis = RBFBasis(centres=np.array([[0.0], [1.0]]), sigma2=0.5).fit(np.zeros((1, 1)))
    g0, g1 = np.exp(-(0.25**2) / 1.0), np.exp(-(0.75**2) / 1.0)
    np.testing.assert_allclose(basis.transform(np.array([[0.25]]))[0], [g0 / (g0 + g1), g1 / (g0 + g1)])


def test_default_width_includes_self_pairs():
    c = np.array([[0.0, 0.0], [3.0, 4.0]])
    # pairs (0,0),(0,1),(1,0),(1,1): distances 0,5,5,0 → mean 2.5
    assert default_sigma2(c) == 2.5**2


def test_grid_centres_in_any_dimension():
    X = np.random.default_rng(1).uniform(0, 1, (50, 3))
    c = grid_centres(X, 30)
    assert c.shape == (27, 3)  # floor(30^(1/3)) = 3 per axis
    np.testing.assert_allclose(c.min(0), X.min(0) - 0.1)
    np.testing.assert_allclose(c.max(0), X.max(0) + 0.1)


def test_kmeans_is_seeded_and_finds_clusters():
    rng = np.random.default_rng(2)
    blobs = np.vstack([rng.normal(m, 0.01, (50, 2)) for m in ([0, 0], [5, 5], [-5, 5])])
    a = kmeans_centres(blobs, 3, seed=7)
    b = kmeans_centres(blobs, 3, seed=7)
    np.testing.assert_array_equal(a, b)
    found = sorted(map(tuple, np.round(a).astype(int)))
    assert found == [(-5, 5), (0, 0), (5, 5)]


def test_kmeans_reseeds_empty_clusters():
    X = np.vstack([np.zeros((10, 1)), np.ones((10, 1))])  # two distinct values, four centres
    c = kmeans_centres(X, 4, seed=0)
    assert np.isfinite(c).all() and c.shape == (4, 1)


def test_linear_basis():
    X = np.array([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(LinearBasis().fit(X).transform(X), [[1, 2, 1], [3, 4, 1]])
