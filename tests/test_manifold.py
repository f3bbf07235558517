"""The manifold of the states (learn/constraint/manifold.py) and the constraints the states' own
geometry shows (learn/constraint/geometry.py): learnt rows against the geometry that made the
data, the shipped real hinge and slide logs against circles and lines fitted to them, and the
answer unchanged by the frame, the length unit and the order of the demonstrations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ccl_cli.errors import InputError
from ccl_cli.learn.constraint.geometry import circle, decide, drift, revisits
from ccl_cli.learn.constraint.manifold import ManifoldConstraint, features

ARTICULATION = Path(__file__).resolve().parent.parent / "sample_data" / "articulation"


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def largest_angle(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Largest principal angle (degrees) between the row spaces of R1 and R2, per sample: (N, k, q) → (N,)."""
    Q1 = np.linalg.qr(np.swapaxes(R1, 1, 2))[0]
    Q2 = np.linalg.qr(np.swapaxes(R2, 1, 2))[0]
    s = np.linalg.svd(np.swapaxes(Q1, 1, 2) @ Q2, compute_uv=False)
    return np.degrees(np.arccos(np.clip(s.min(axis=1), 0.0, 1.0)))


def hinge(n_demos: int = 6, noise: float = 5e-4, seed: int = 0):
    """Arcs about the z axis through (0.3, 0.2, ·): per demonstration its own radius and height
    (offsets), 50–80° swept; rows axis and radial. → X (N, 3), groups (N,), rows (N, 2, 3)."""
    rng = np.random.default_rng(seed)
    centre = np.array([0.3, 0.2, 0.0])
    X, g = [], []
    for d in range(n_demos):
        r, z = rng.uniform(0.5, 0.6), rng.uniform(-0.1, 0.1)
        a0 = rng.uniform(0, 2 * np.pi)
        a = a0 + np.linspace(0, np.radians(rng.uniform(50, 80)), 300)
        P = centre + np.c_[r * np.cos(a), r * np.sin(a), np.full_like(a, z)]
        X.append(P + rng.normal(scale=noise, size=P.shape))
        g.append(np.full(len(a), d))
    X, g = np.vstack(X), np.concatenate(g)
    radial = unit((X - centre) * [1, 1, 0])
    rows = np.stack([np.broadcast_to([0.0, 0.0, 1.0], X.shape), radial], 1)
    return X, g, rows


def plane_strokes(n_demos: int = 4, noise: float = 1e-3, seed: int = 0):
    """Loops drawn over and over on a tilted plane (a finger tracing circles on a table):
    one row, the plane's normal."""
    rng = np.random.default_rng(seed)
    normal = unit(np.array([0.2, -0.3, 1.0]))
    e1 = unit(np.cross(normal, [0, 0, 1.0]))
    e2 = np.cross(normal, e1)
    X, g = [], []
    for d in range(n_demos):
        t = np.linspace(0, 6 * 2 * np.pi, 1500)
        wander = 0.02 * np.c_[np.sin(0.13 * t), np.cos(0.11 * t)]
        p = np.c_[0.06 * np.cos(t), 0.04 * np.sin(1.0 * t)] + wander + rng.uniform(-0.05, 0.05, 2)
        P = np.outer(p[:, 0], e1) + np.outer(p[:, 1], e2) + rng.normal(scale=noise, size=(len(t), 3))
        X.append(P)
        g.append(np.full(len(t), d))
    return np.vstack(X), np.concatenate(g), normal


def free_reaches(n_demos: int = 8, seed: int = 0):
    """Curved reaches from scattered starts to one goal: no constraint."""
    rng = np.random.default_rng(seed)
    goal = np.array([0.5, 0.0, 0.3])
    X, g = [], []
    for d in range(n_demos):
        start = goal + rng.uniform(-0.3, 0.3, 3)
        s = np.linspace(0, 1, 200)[:, None]
        bow = rng.normal(scale=0.08, size=3)
        P = start + (goal - start) * (3 * s**2 - 2 * s**3) + bow * np.sin(np.pi * s)
        X.append(P + rng.normal(scale=2e-4, size=P.shape))
        g.append(np.full(len(s), d))
    return np.vstack(X), np.concatenate(g)


def test_features_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    Z = rng.normal(size=(5, 3))
    for basis in ("linear", "sphere", "quadric"):
        _, J = features(basis, Z)
        eps = 1e-6
        for j in range(3):
            dZ = np.zeros(3)
            dZ[j] = eps
            fd = (features(basis, Z + dZ)[0] - features(basis, Z - dZ)[0]) / (2 * eps)
            np.testing.assert_allclose(J[:, :, j], fd, atol=1e-8)


def test_sphere_basis_learns_a_hinge_axis_and_radial_row():
    X, g, rows = hinge()
    model = ManifoldConstraint(family="sphere", n_constraints=2).fit(X, X, groups=g)
    assert np.median(largest_angle(model.constraint(X), rows)) < 0.5
    # each level function is (nearly) constant along each demonstration: its variation is the noise
    assert np.sqrt(model.variation_[:2]).max() < 3e-3


def test_linear_basis_cannot_hold_a_hinge_but_holds_a_line():
    X, g, _ = hinge()
    assert drift(X, g, "linear", 2)[1] > 0.1
    rng = np.random.default_rng(3)
    d = unit(np.array([1.0, 0.4, -0.2]))
    offsets = rng.normal(scale=0.1, size=(6, 3))
    s = np.linspace(0, 0.4, 150)[:, None]
    X = np.vstack([o + s * d + rng.normal(scale=1e-3, size=(150, 3)) for o in offsets])
    g = np.repeat(np.arange(6), 150)
    model = ManifoldConstraint(family="linear", n_constraints=2).fit(X, X, groups=g)
    A = model.constraint(X[:1])[0]
    np.testing.assert_allclose(A @ d, 0.0, atol=2e-3)
    assert drift(X, g, "linear", 2).max() < 0.01


def test_automatic_rank_of_the_manifold_learner():
    X, g, normal = plane_strokes()
    model = ManifoldConstraint(family="linear").fit(X, X, groups=g)
    assert model.n_constraints_ == 1
    assert abs(model.constraint(X[:1])[0, 0] @ normal) > np.cos(np.radians(1))


def test_states_and_actions_of_different_dimensions_are_refused():
    X, g, _ = hinge()
    with pytest.raises(InputError, match="one dimension"):
        ManifoldConstraint().fit(X, X[:, :2], groups=g)


def test_decide_hinge_plane_and_free_motion():
    X, g, rows = hinge()
    found = decide(X, g)
    assert found.k == 2 and found.winner.basis == "sphere"
    X, g, normal = plane_strokes()
    found = decide(X, g)
    assert found.k == 1 and found.winner.basis == "linear"
    X, g = free_reaches()
    found = decide(X, g)
    assert found.k == 0 and found.winner is None
    assert all(not t.holds for t in found.tried)


def test_revisits_tell_loops_from_a_single_pass():
    X, g, _ = plane_strokes()
    assert revisits(X[g == 0]) > 0.8
    X, g = free_reaches()
    assert revisits(X[g == 0]) < 0.05
    X, g, _ = plane_strokes()
    share = revisits(X[g == 0])
    assert revisits(X[g == 0] * 1e250) == share  # no overflow in the tree's distances (was a ValueError)


def _logs(kind: str) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    files = sorted((ARTICULATION / kind).glob("*.log"))
    parts = [np.loadtxt(f)[:, :3] for f in files]
    return np.vstack(parts), np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)]), parts


def test_real_dishwasher_is_a_hinge_per_demonstration():
    X, g, parts = _logs("dishwasher")
    found = decide(X, g)
    assert found.k == 2 and found.winner.scope == "per_demo" and found.winner.basis == "sphere"
    # the learnt rows against the circle fitted to each log (plane by SVD, circle in it)
    angles = []
    for P in parts:
        axis, _ = circle(P)
        c0 = P.mean(0)
        e1, e2, _ = np.linalg.svd(P - c0, full_matrices=False)[2]
        Q = np.c_[(P - c0) @ e1, (P - c0) @ e2]
        sol = np.linalg.lstsq(np.c_[2 * Q, np.ones(len(Q))], (Q**2).sum(1), rcond=None)[0]
        centre = c0 + sol[0] * e1 + sol[1] * e2
        radial = unit((P - centre) - np.outer((P - centre) @ axis, axis))
        truth = np.stack([np.broadcast_to(axis, P.shape), radial], 1)
        model = ManifoldConstraint(family="sphere", n_constraints=2).fit(P, P)
        angles.append(np.median(largest_angle(model.constraint(P), truth)))
    assert max(angles) < 1.0


def test_real_drawer_is_a_family_of_parallel_lines():
    X, g, parts = _logs("drawer")
    found = decide(X, g)
    assert found.k == 2 and found.winner.scope == "global" and found.winner.basis == "linear"
    model = ManifoldConstraint(family="linear", n_constraints=2).fit(X, X, groups=g)
    A = model.constraint(X[:1])[0]
    for P in parts:  # each log's own line, by SVD
        d = np.linalg.svd(P - P.mean(0), full_matrices=False)[2][0]
        assert np.degrees(np.arcsin(min(1.0, np.linalg.norm(A @ d)))) < 5.0


rotations = st.tuples(*[st.floats(-np.pi, np.pi)] * 3)


def _rotation(a: float, b: float, c: float) -> np.ndarray:
    def r(i, j, t):
        R = np.eye(3)
        R[[i, i, j, j], [i, j, i, j]] = [np.cos(t), -np.sin(t), np.sin(t), np.cos(t)]
        return R
    return r(0, 1, a) @ r(1, 2, b) @ r(0, 2, c)


@settings(max_examples=8, deadline=None)
@given(angles=rotations, shift=st.tuples(*[st.floats(-5, 5)] * 3), scale=st.sampled_from([1e-3, 1.0, 1e3]),
       reverse=st.booleans())
def test_the_answer_does_not_depend_on_frame_unit_or_order(angles, shift, scale, reverse):
    X, g, rows = hinge(n_demos=5, seed=4)
    R = _rotation(*angles)
    Y = (X @ R.T + np.array(shift)) * scale
    h = g
    if reverse:  # demonstrations in the opposite order
        order = np.concatenate([np.flatnonzero(g == d) for d in np.unique(g)[::-1]])
        Y, h, rows = Y[order], g[order], rows[order]
    base, moved = decide(X, g), decide(Y, h)
    assert (moved.k, moved.winner.scope, moved.winner.basis) == (base.k, base.winner.scope, base.winner.basis)
    np.testing.assert_allclose(np.sort(moved.winner.drift), np.sort(base.winner.drift), rtol=1e-6, atol=1e-9)
    model = ManifoldConstraint(family="sphere", n_constraints=2).fit(Y, Y, groups=h)
    assert np.median(largest_angle(model.constraint(Y), rows @ R.T)) < 0.5


def test_demonstrations_held_still_or_too_short_show_nothing():
    """A demonstration that does not move, or a scrap of a few samples, neither vetoes nor
    makes a shape: the hinge is found on the others, and with nothing moving k = 0 with a reason."""
    X, g, _ = hinge()
    still = np.repeat(X[:1], 60, axis=0)
    scrap = X[:4] + 0.3
    Y = np.vstack([X, still, scrap])
    h = np.r_[g, np.full(60, 100), np.full(4, 101)]
    found = decide(Y, h)
    assert found.k == 2 and found.winner.basis == "sphere"
    nothing = decide(np.repeat(X[:1], 50, axis=0))
    assert nothing.k == 0 and "no demonstration moves" in nothing.reason


def test_a_row_the_contact_gives_along_is_kept_by_the_positions():
    """The noise rule stops at a row whose motion is far above the noise (a contact that gives, a
    smooth wobble of a few mm); the positions do not drift along it: the row is kept. A row in the
    plane is not."""
    from ccl_cli.learn.constraint.geometry import add_still_rows
    from ccl_cli.learn.constraint.rank import Selection

    X, g, normal = plane_strokes(noise=0.0)
    t = np.arange(len(X)) * 0.02
    X = X + np.outer(0.002 * np.sin(2 * np.pi * t / 0.7), normal)  # 2 mm of give, well above any noise
    U = np.gradient(X, t, axis=0)
    in_plane = unit(np.cross(normal, [1.0, 0, 0]))
    for rows, kept in ((np.stack([normal, in_plane]), 1), (np.stack([in_plane, normal]), 0)):
        rows = np.broadcast_to(rows, (len(X), 2, 3))
        chosen = add_still_rows(Selection("noise", 0, [], "row 1 moves"), rows, X, U, g, t, {"window": 5}, 2)
        assert chosen.n_constraints == kept


def test_rows_each_demonstration_moves_along_at_a_constant_rate_are_a_task_part():
    """The varying-constraint tutorial with a task part (A u = b per demonstration): the states drift
    along each one's row at its own constant rate; the geometry finds one row per demonstration and
    learn-a's auto fits each with its task term — NPPE < 0.1 — while free motion stays at k = 0."""
    from ccl_cli import simulate as sim
    from ccl_cli.learn.constraint import AutoConstraint

    d = sim.varying_constraint(task=True, noise=0.01, seed=0)
    found = decide(d.X, d.demo, t=d.t)
    assert found.k == 1 and found.winner.scope == "per_demo_task" and found.winner.worst < 0.02
    model = AutoConstraint().fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative)
    assert model.selection_["chosen"] == "per_demo_task"
    N = model.projection(d.X, groups=d.demo)
    Pi = d.truth["pi"]
    nppe = np.mean(((d.true_projection() - N) @ Pi[:, :, None]) ** 2) * 2 / np.var(d.U, axis=0, ddof=1).sum()
    assert nppe < 0.1
    free = sim.flow2d(seed=0)
    assert decide(free.X, free.demo, t=free.t).k == 0


def test_the_generalised_eigenproblem_without_scipy_matches_scipys():
    from scipy.linalg import eigh

    from ccl_cli.learn.linalg import generalized_eigh

    rng = np.random.default_rng(0)
    for d in (2, 3, 6, 10):
        M, N = rng.normal(size=(200, d)), rng.normal(size=(200, d)) * rng.uniform(0.01, 10, d)
        A, B = M.T @ M / 200, N.T @ N / 200
        lam, W = generalized_eigh(A, B)
        ref, V = eigh(A, B)
        np.testing.assert_allclose(lam, ref, rtol=1e-9)
        np.testing.assert_allclose(W.T @ B @ W, np.eye(d), atol=1e-10)  # B-orthonormal
        np.testing.assert_allclose(np.abs(np.sum(W * (B @ V), 0)), 1.0, atol=1e-9)  # the same directions


def test_returning_counts_passes_as_a_kd_trees_ball_query():
    from scipy.spatial import cKDTree

    from ccl_cli.learn.constraint import geometry

    rng = np.random.default_rng(1)
    for n in (3, 50, 2000):
        t = np.linspace(0, 20, n)
        P = np.c_[np.cos(t), np.sin(t), 0.1 * t] + rng.normal(scale=0.01, size=(n, 3))
        Q, r = P[:: max(1, n // 400)], 0.3
        near = cKDTree(P).query_ball_point(Q, r, return_sorted=True)
        runs = [np.count_nonzero(np.diff(nb) != 1) + 1 for nb in near]
        np.testing.assert_array_equal(geometry.passes_near(P, Q, r), runs)
    assert geometry.returning(P).mean() == pytest.approx(0.0, abs=0.1)  # a helix: no second pass
