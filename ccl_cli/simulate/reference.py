"""Reference problems with ground truth (ALGORITHMS.md §7). Every function is seeded.

Each returns :class:`~ccl_cli.dataset.Demonstrations` with ``truth`` holding
``pi`` (unconstrained policy), ``w = Nπ``, ``v = A⁺b``, ``b``, ``A`` and ``N``.
Observation noise (``noise`` std, or ``snr_db``) is added to ``U`` only; the state
is integrated with the noise-free action — except in the tracker recordings
(``tracker_plane``, ``tracker_sphere``), where the noise is on the positions and the
velocities are derived from them as the readers do. ``arm_at_rest`` is a recording with
nothing to learn (for the data diagnostics).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import ConfigError
from ccl_cli.learn.kinematics import SevenDofArm, TwoLinkArm
from ccl_cli.learn.linalg import nullspace_projection, unit_rows

Policy = Callable[[np.ndarray], np.ndarray]

#: The fixed matrix of the toy "linear" policy π(x) = M x.
LINEAR_POLICY = np.array([[-0.5, 1.0], [-1.0, -0.5]])


ESCAPE = 5.0  # toy trajectories end beyond five times the sampling box


def toy_policy(name: str) -> Policy:
    """Null-space policies of the toy problem: attractor, limit_cycle, linear."""
    if name == "attractor":
        return lambda X: 0.5 * (0.0 - X)
    if name == "limit_cycle":
        r, omega = 0.75, 1.0

        def limit_cycle(X: np.ndarray) -> np.ndarray:
            rad = r - (X**2).sum(1)
            return -np.stack([rad * X[:, 0] - X[:, 1] * omega, rad * X[:, 1] + X[:, 0] * omega], 1)

        return limit_cycle
    if name == "linear":
        return lambda X: X @ LINEAR_POLICY.T
    raise ConfigError(f"unknown toy policy {name!r} (use attractor, limit_cycle or linear)")


def _noise(rng: np.random.Generator, U: np.ndarray, std: float | None, snr_db: float | None) -> np.ndarray:
    if snr_db is not None:
        power = np.mean(U**2, axis=0)
        std_d = np.sqrt(power / 10.0 ** (snr_db / 10.0))
        return U + rng.normal(size=U.shape) * std_d
    if std:
        return U + rng.normal(scale=std, size=U.shape)
    return U.copy()


def _compose(X, pi, A, b, rng, noise, snr_db, demo, t, names=None, cut=None) -> Demonstrations:
    """Build the dataset from per-sample X, π, A (N, s, q), b (N, s)."""
    N = nullspace_projection(A)
    v = np.einsum("nqs,ns->nq", np.linalg.pinv(A), b)
    w = np.einsum("nij,nj->ni", N, pi)
    U_true = v + w
    keep = np.ones(len(X), bool) if cut is None else cut
    U = _noise(rng, U_true[keep], noise, snr_db)
    truth = {"pi": pi[keep], "w": w[keep], "v": v[keep], "b": b[keep], "A": A[keep], "N": N[keep]}
    return Demonstrations(X=X[keep], U=U, demo=demo[keep], t=t[keep], truth=truth,
                          state_names=names, metadata={})


def _toy_constraint(kind: str, X: np.ndarray, a: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A (N, 1, 2): the fixed unit row ``rows`` or the parabola [2a x₁, −1] (normalised)."""
    if kind == "fixed":
        return rows[:, None, :]
    if kind == "parabola":
        return unit_rows(np.stack([2.0 * a * X[:, 0], -np.ones(len(X))], 1))[:, None, :]
    raise ConfigError(f"unknown toy constraint {kind!r} (use fixed or parabola)")


def toy2d(
    constraint: str = "fixed",
    policy: str = "attractor",
    task: bool = False,
    sampling: str = "trajectory",
    n_demos: int = 50,
    n_steps: int = 20,
    dt: float = 0.1,
    n_samples: int = 500,
    vary_constraint: bool = False,
    a: float = 2.0,
    noise: float = 0.01,
    snr_db: float | None = None,
    seed: int = 0,
) -> Demonstrations:
    """Toy 2-D problem: x ∈ [−1, 1]², q = 2, one constraint.

    Args:
        constraint: ``fixed`` (a random unit row) or ``parabola`` (A = [2a x₁, −1]).
        policy: ``attractor`` π = −0.5x, ``limit_cycle`` (r = 0.75, ω = 1), ``linear``.
        task: add a task part b ~ U(−1, 1) (per sample when uniform, per demo otherwise).
        sampling: ``trajectory`` (Euler, ``dt``, ``n_steps``, stopped when ‖w‖ < 1e-3, or
            when the state leaves [−ESCAPE, ESCAPE]²: the limit cycle of §7 repels, so a
            start outside it spirals out and would overflow)
            or ``uniform`` (``n_samples`` states uniform in the box, dealt round-robin
            into ``n_demos`` groups).
        vary_constraint: a new constraint per demonstration (a random unit row, or
            a ~ U(0.5, 3) for the parabola); needed to learn π.
    """
    rng = np.random.default_rng(seed)
    pol = toy_policy(policy)
    rows = unit_rows(rng.normal(size=(n_demos, 2))) if vary_constraint else np.repeat(
        unit_rows(rng.normal(size=(1, 2))), n_demos, 0)
    a_demo = rng.uniform(0.5, 3.0, n_demos) if vary_constraint else np.full(n_demos, a)
    if sampling == "uniform":
        X = rng.uniform(-1.0, 1.0, (n_samples, 2))
        demo = np.arange(n_samples) % n_demos
        t = (np.arange(n_samples) // n_demos).astype(float) * dt
        A = _toy_constraint(constraint, X, a_demo[demo], rows[demo])
        b = rng.uniform(-1, 1, (n_samples, 1)) if task else np.zeros((n_samples, 1))
        order = np.argsort(demo, kind="stable")
        X, demo, t, A, b = X[order], demo[order], t[order], A[order], b[order]
        return _compose(X, pol(X), A, b, rng, noise, snr_db, demo, t)
    if sampling != "trajectory":
        raise ConfigError(f"unknown sampling {sampling!r} (use trajectory or uniform)")
    b_demo = rng.uniform(-1, 1, (n_demos, 1)) if task else np.zeros((n_demos, 1))
    x = rng.uniform(-1.0, 1.0, (n_demos, 2))
    Xs, As, Bs, Ps, alive = [], [], [], [], []
    live = np.ones(n_demos, bool)
    for _ in range(n_steps):  # loop over time steps; all demonstrations at once
        A = _toy_constraint(constraint, x, a_demo, rows)
        pi = pol(x)
        N = nullspace_projection(A)
        w = np.einsum("nij,nj->ni", N, pi)
        v = np.einsum("nqs,ns->nq", np.linalg.pinv(A), b_demo)
        live &= (np.linalg.norm(w, axis=1) >= 1e-3) & np.all(np.abs(x) <= ESCAPE, axis=1)
        Xs.append(x.copy()), As.append(A), Bs.append(b_demo), Ps.append(pi), alive.append(live.copy())
        x = x + dt * (v + w) * live[:, None]  # ended trajectories stay put (then cut)
    return _stack_trajectories(Xs, As, Bs, Ps, alive, dt, rng, noise, snr_db)


def _stack_trajectories(Xs, As, Bs, Ps, alive, dt, rng, noise, snr_db, names=None) -> Demonstrations:
    """(T lists of (D, ...)) → samples ordered by demo then time, dead steps removed."""
    def stack(seq):
        arr = np.stack(seq, 1)  # (D, T, ...)
        return arr.reshape(-1, *arr.shape[2:])

    n_demos, n_steps = len(Xs[0]), len(Xs)
    demo = np.repeat(np.arange(n_demos), n_steps)
    t = np.tile(np.arange(n_steps) * dt, n_demos)
    cut = stack(alive)
    return _compose(stack(Xs), stack(Ps), stack(As), stack(Bs), rng, noise, snr_db, demo, t,
                    names=names, cut=cut)


def two_link(
    n_demos: int = 40,
    n_steps: int = 40,
    dt: float = 0.01,
    a: float = 2.0,
    target_deg: tuple[float, float] = (10.0, -10.0),
    task: bool = False,
    noise: float = 0.0,
    seed: int = 0,
) -> Demonstrations:
    """2-link planar arm in joint space: A(q) = Λ(q) J(q), Λ = [2a·x_ee, −1] (normalised),
    π = q* − q with q* = (10°, −10°); start near (0°, 90°) + U(0°, 10°) per joint.

    ``task`` adds a task part (the ncl problem, u = A⁺b + N π): b ~ U(−1, 1) per
    demonstration, constant along it, as for the toy's ncl tutorial (ALGORITHMS.md §7)."""
    rng = np.random.default_rng(seed)
    arm = TwoLinkArm()
    target = np.deg2rad(np.asarray(target_deg))
    q = np.deg2rad(np.array([0.0, 90.0]) + rng.uniform(0.0, 10.0, (n_demos, 2)))
    b = rng.uniform(-1.0, 1.0, (n_demos, 1)) if task else np.zeros((n_demos, 1))
    Xs, As, Bs, Ps, alive = [], [], [], [], []
    for _ in range(n_steps):
        A = two_link_constraint(q, a, arm)
        pi = target - q
        u = (np.einsum("nij,nj->ni", nullspace_projection(A), pi)
             + np.einsum("nqs,ns->nq", np.linalg.pinv(A), b))
        Xs.append(q.copy()), As.append(A), Bs.append(b), Ps.append(pi)
        alive.append(np.ones(n_demos, bool))
        q = q + dt * u
    return _stack_trajectories(Xs, As, Bs, Ps, alive, dt, rng, noise, None, names=["q1", "q2"])


def two_link_constraint(Q: np.ndarray, a: float = 2.0, arm: TwoLinkArm | None = None) -> np.ndarray:
    """A(q) = Λ(x_ee(q)) J(q) with Λ = unit([2a·x_ee, −1]): (N, 2) → (N, 1, 2)."""
    arm = arm or TwoLinkArm()
    lam = unit_rows(np.stack([2.0 * a * arm.forward(Q)[:, 0], -np.ones(len(Q))], 1))
    return np.einsum("nr,nrq->nq", lam, arm.jacobian(Q))[:, None, :]


def arm7(
    rows: tuple[int, ...] = (0, 1),
    constraint: str = "fixed",
    n_demos: int = 50,
    n_steps: int = 40,
    dt: float = 0.05,
    noise: float = 0.01,
    seed: int = 0,
) -> Demonstrations:
    """7-DoF arm, π = q* − q in joint space under A = Λ J with Λ selecting ``rows`` of
    the geometric Jacobian (0–2 position, 3–5 orientation).

    ``constraint="fixed"`` evaluates the Jacobian once at a seeded reference posture
    (a state-independent constraint of rank len(rows)); ``"jacobian"`` uses A(q) = ΛJ(q).
    Initial postures and q* are uniform within ± half the joint limits.
    """
    rng = np.random.default_rng(seed)
    arm = SevenDofArm()
    half = np.deg2rad(arm.limits_deg) / 2.0
    target = rng.uniform(-half, half)
    q = rng.uniform(-half, half, (n_demos, 7))
    sel = list(rows)
    if constraint == "fixed":
        q_ref = rng.uniform(-half, half)[None, :]
        A_fixed = arm.jacobian(q_ref)[:, sel, :]
    elif constraint != "jacobian":
        raise ConfigError(f"unknown arm7 constraint {constraint!r} (use fixed or jacobian)")
    s = len(sel)
    Xs, As, Bs, Ps, alive = [], [], [], [], []
    for _ in range(n_steps):
        A = np.repeat(A_fixed, n_demos, 0) if constraint == "fixed" else arm.jacobian(q)[:, sel, :]
        pi = target - q
        u = np.einsum("nij,nj->ni", nullspace_projection(A), pi)
        Xs.append(q.copy()), As.append(A), Bs.append(np.zeros((n_demos, s))), Ps.append(pi)
        alive.append(np.ones(n_demos, bool))
        q = q + dt * u
    names = [f"q{i + 1}" for i in range(7)]
    return _stack_trajectories(Xs, As, Bs, Ps, alive, dt, rng, noise, None, names=names)


def varying_constraint(
    n_demos: int = 50,
    duration: float = 2.0,
    rate: float = 50.0,
    rho: float = -0.5,
    task: bool = False,
    snr_db: float | None = None,
    noise: float = 0.0,
    seed: int = 0,
) -> Demonstrations:
    """Armesto et al.'s toy: limit cycle ṙ = r(ρ − r²), θ̇ = 1, i.e.
    π(x) = (ρ − ‖x‖²) x + [−x₂, x₁]; each demonstration has A = [cos t₀, sin t₀],
    t₀ ~ U(0, 2π), optionally b₀ ~ U(−0.3, 0.3); ``duration`` s at ``rate`` Hz from
    x₀ ~ U(−1, 1)²; noise as ``snr_db`` (per dimension) or std ``noise``."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    n_steps = int(round(duration * rate))
    t0 = rng.uniform(0.0, 2 * np.pi, n_demos)
    A_demo = np.stack([np.cos(t0), np.sin(t0)], 1)[:, None, :]
    b_demo = rng.uniform(-0.3, 0.3, (n_demos, 1)) if task else np.zeros((n_demos, 1))
    x = rng.uniform(-1.0, 1.0, (n_demos, 2))
    Xs, As, Bs, Ps, alive = [], [], [], [], []
    for _ in range(n_steps):
        pi = armesto_policy(x, rho)
        N = nullspace_projection(A_demo)
        u = np.einsum("nij,nj->ni", N, pi) + np.einsum("nqs,ns->nq", np.linalg.pinv(A_demo), b_demo)
        Xs.append(x.copy()), As.append(A_demo), Bs.append(b_demo), Ps.append(pi)
        alive.append(np.ones(n_demos, bool))
        x = x + dt * u
    return _stack_trajectories(Xs, As, Bs, Ps, alive, dt, rng, noise, snr_db)


def armesto_policy(X: np.ndarray, rho: float = -0.5) -> np.ndarray:
    """π(x) = (ρ − ‖x‖²) x + [−x₂, x₁] (the polar limit cycle in Cartesian form)."""
    rad = rho - (X**2).sum(1, keepdims=True)
    return rad * X + np.stack([-X[:, 1], X[:, 0]], 1)
