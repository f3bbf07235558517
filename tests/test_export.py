"""``ccl export`` (issue 29): a saved model as a versioned YAML / JSON file that is evaluated
without ccl. Every model here is learnt and applied by the ``ccl`` commands (simulated and shipped
real recordings); the exported file is evaluated by the reference evaluator of docs/export.md —
copied below, reading only the file with yaml / json and numpy, never ccl's learners — and must
equal ``ccl predict`` to 1e-12 on a recording the model has not seen: every form of constraint
(each one ``auto`` can choose, and the explicit methods), a null-space component and policies.
Models per stretch are also checked on the demonstrations they were fitted on (their entries,
against the loaded model's projection), and the command keeps the CLI's conventions."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from ccl_cli.cli import main

ROOT = Path(__file__).resolve().parent.parent
ARTICULATION = ROOT / "sample_data" / "articulation"
TOL = 1e-12

# ---- reference evaluator (docs/export.md's, copied: test_the_docs_hold_the_evaluator_tested_here) ----
def load(path):
    """The exported document; anything but a ccl model export of schema version 1 is refused."""
    with open(path, encoding="utf-8") as f:
        doc = json.load(f) if str(path).endswith(".json") else yaml.safe_load(f)
    if doc.get("format") != "ccl-model-export" or doc.get("schema_version") != 1:
        raise ValueError(f"{path}: not a ccl model export of schema version 1")
    return doc


# -- features ------------------------------------------------------------------------------
def features(basis, X):
    """β(X): (N, p) → (N, K)."""
    if basis["kind"] == "linear":
        return np.hstack([X, np.ones((len(X), 1))])
    c = np.asarray(basis["centres"])
    d2 = np.maximum((X * X).sum(1)[:, None] - 2.0 * X @ c.T + (c * c).sum(1)[None, :], 0.0)
    g = -d2 / (2.0 * basis["sigma2"])
    g = np.exp(g - g.max(1, keepdims=True))
    return g / g.sum(1, keepdims=True)


def regressors(r, X):
    """f(X) of a linear model's regressors: (N, M)."""
    if r["kind"] == "constant":
        return np.ones((len(X), 1))
    if r["kind"] == "polynomial":
        return np.prod(X[:, None, :] ** np.asarray(r["monomials"])[None], axis=2)
    return features(r["basis"], X)


def jacobian(f, X):
    """Φ(X): rows of the geometric Jacobian of a standard DH chain at joint angles X (N, n)."""
    if f["kind"] != "dh":
        raise ValueError("a URDF chain: compute Φ(x) with your kinematics library")
    a, alpha, d = (np.asarray(f["dh"][key], float) for key in ("a", "alpha", "d"))
    n = len(X)
    T, z, o = np.tile(np.eye(4), (n, 1, 1)), [], []
    for i in range(X.shape[1]):
        z.append(T[:, :3, 2])
        o.append(T[:, :3, 3])
        ct, st, ca, sa = np.cos(X[:, i]), np.sin(X[:, i]), np.cos(alpha[i]), np.sin(alpha[i])
        A = np.zeros((n, 4, 4))
        A[:, 0] = np.stack([ct, -st * ca, st * sa, a[i] * ct], 1)
        A[:, 1] = np.stack([st, ct * ca, -ct * sa, a[i] * st], 1)
        A[:, 2, 1:] = [sa, ca, d[i]]
        A[:, 3, 3] = 1.0
        T = T @ A
    z, o = np.stack(z, 2), np.stack(o, 2)  # (N, 3, n)
    J = np.concatenate([np.cross(z, T[:, :3, 3:] - o, axis=1), z], 1)  # (N, 6, n): v, ω
    return J[:, f["rows"]]


# -- A(x) of a model for all states ----------------------------------------------------------
def unit_vector(theta):
    """a(θ): (N, m) → (N, m + 1), unit vectors in hyperspherical angles."""
    n, m = theta.shape
    prefix = np.ones((n, m + 1))
    prefix[:, 1:] = np.cumprod(np.sin(theta), 1)
    return np.hstack([np.cos(theta) * prefix[:, :m], prefix[:, m:]])


def angle_rows(body, X):
    """Rows (N, k, d) of the angle parametrisation (form angles; known_features' Λ)."""
    B, d = features(body["basis"], X), body["dimension"]
    Q = np.tile(np.eye(d), (len(X), 1, 1))
    rows = []
    for j, W in enumerate(body["weights"]):
        theta = B @ np.asarray(W).T
        rows.append(np.einsum("nj,njc->nc", unit_vector(theta), Q[:, j:]))
        R = np.tile(np.eye(d - j), (len(X), 1, 1))  # R(θ) = G_m ⋯ G_1
        for i in range(d - j - 1):
            c, s = np.cos(theta[:, i])[:, None], np.sin(theta[:, i])[:, None]
            R[:, i], R[:, i + 1] = c * R[:, i] - s * R[:, i + 1], s * R[:, i] + c * R[:, i + 1]
        Q[:, j:] = np.einsum("nji,njc->nic", R, Q[:, j:])
    return np.stack(rows, 1) if rows else np.zeros((len(X), 0, d))


def manifold_features(basis, Z):
    """φ(z) (N, F) and ∂φ/∂z (N, F, q) at scaled states Z (N, q)."""
    n, q = Z.shape
    eye = np.tile(np.eye(q), (n, 1, 1))
    if basis == "linear":
        return Z, eye
    if basis == "sphere":
        return np.c_[Z, (Z**2).sum(1)], np.concatenate([eye, 2 * Z[:, None, :]], 1)
    a, b = np.triu_indices(q)
    J = np.zeros((n, len(a), q))
    J[:, np.arange(len(a)), a] += Z[:, b]
    J[:, np.arange(len(a)), b] += Z[:, a]
    return np.c_[Z, Z[:, a] * Z[:, b]], np.concatenate([eye, J], 1)


def manifold_rows(body, X):
    """The orthonormalised gradients of the level functions (form manifold): (N, k, q)."""
    _, J = manifold_features(body["basis"], (X - np.asarray(body["centre"])) / body["scale"])
    G = np.einsum("kf,nfq->nkq", np.asarray(body["levels"]), J)
    Q, R = np.linalg.qr(np.swapaxes(G, 1, 2))  # Gram–Schmidt, each row keeping its gradient's sign
    sign = np.sign(np.einsum("nkk->nk", R))
    sign[sign == 0] = 1.0
    return np.swapaxes(Q, 1, 2) * sign[:, :, None]


def returning(P, radius, queries):
    """Per sample of one demonstration P (n, q): two other passes of it (runs of consecutive
    samples) within radius × its RMS spread; every step-th sample asked, the others take the
    answer of the nearest one asked (form manifold_phases): (n,) bool."""
    scale = np.abs(P).max() if P.size else 0.0
    if len(P) < 3 or not 0 < scale < np.inf:
        return np.zeros(len(P), bool)
    P = P / scale
    spread = np.sqrt(((P - P.mean(0)) ** 2).sum(1).mean())
    if not spread > 0:
        return np.zeros(len(P), bool)
    step = max(1, len(P) // queries)
    asked = np.arange(0, len(P), step)
    back = [np.count_nonzero(np.diff(np.flatnonzero(np.sqrt(((P - P[i]) ** 2).sum(1)) <= radius * spread))
                             != 1) >= 2 for i in asked]
    return np.array(back)[np.minimum((np.arange(len(P)) + step // 2) // step, len(asked) - 1)]


def phase_rows(body, X, demo):
    """A(X) (N, k, q) of form manifold_phases: the manifold's rows where the levels h(x) lie within
    tol × spread of the median level of a run of the sample's demonstration that comes back over
    its ground (runs of at least min_share of the demonstration), rows of zeros elsewhere."""
    r = body["phases"]
    Phi, _ = manifold_features(body["basis"], (X - np.asarray(body["centre"])) / body["scale"])
    H = Phi @ np.asarray(body["levels"]).T * body["scale"]
    on = np.zeros(len(X), bool)
    for d in np.unique(demo):
        m = np.flatnonzero(demo == d)
        back = returning(X[m], r["radius"], r["queries"])
        edges = np.flatnonzero(np.diff(np.r_[0, back.astype(int), 0]))
        levels = [np.median(H[m][a:b], axis=0) for a, b in zip(edges[::2], edges[1::2], strict=True)
                  if b - a >= r["min_share"] * len(m)]
        if levels:
            off = np.abs(H[m][:, None, :] - np.asarray(levels)[None])
            on[m] = (off <= r["tol"] * np.asarray(body["spread"])).all(-1).any(-1)
    return np.where(on[:, None, None], manifold_rows(body, X), 0.0)

def linear_rows(body, X):
    """A(x) = Σ_m f_m(x) weights[m], or weights Φ(x) (form linear): (N, k, q)."""
    r, W = body["regressors"], np.asarray(body["weights"])
    if r["kind"] == "jacobian":
        return W @ jacobian(r["features"], X)
    return np.einsum("nm,mkq->nkq", regressors(r, X), W)


def rows_of(body, X, q):
    """A(X) (N, k, q) of a form that holds everywhere."""
    form = body["form"]
    if form in ("constant", "none"):
        rows = np.asarray(body["rows"], float).reshape(-1, q)
        return np.broadcast_to(rows, (len(X), *rows.shape))
    if form == "manifold":
        return manifold_rows(body, X)
    if form == "angles":
        return angle_rows(body, X)
    if form == "known_features":
        return angle_rows(body, X) @ jacobian(body["features"], X)
    return linear_rows(body, X)


def projection_of(A, rule, q):
    """N = I − AᵀA (orthonormal), I − A⁺A (pseudo_inverse: the row space from the SVD, singular
    values below 1e-10 × the largest dropped) or I (identity): (N, q, q)."""
    if rule == "identity" or A.shape[1] == 0:
        return np.tile(np.eye(q), (len(A), 1, 1))
    if rule == "orthonormal":
        return np.eye(q) - np.einsum("nki,nkj->nij", A, A)
    _, s, Vt = np.linalg.svd(A, full_matrices=False)
    V = Vt * (s > 1e-10 * np.maximum(s[:, :1], np.finfo(float).tiny))[:, :, None]
    return np.eye(q) - np.einsum("nki,nkj->nij", V, V)


def task_part(doc, X):
    """v(x) = A(x)⁺ b(x) of a linear constraint with a task term: (N, q)."""
    body, X = doc["constraint"], np.asarray(X, float)
    b = regressors(body["task"]["regressors"], X) @ np.asarray(body["task"]["weights"]).T
    return np.einsum("nqk,nk->nq", np.linalg.pinv(linear_rows(body, X), 1e-15), b)


# -- models per stretch: the entries they were fitted on -----------------------------------------
def entry_of(entries, block, demo, t):
    """Index into ``entries`` of each sample of demonstrations ``demo`` at times ``t`` (lookup)."""
    out = np.empty(len(demo), int)
    for d in np.unique(demo):
        mine = np.array([i for i, e in enumerate(entries) if e["demonstration"] == d])
        if not len(mine):
            raise ValueError(f"demonstration {d} is not in the export: use new_data")
        m = demo == d
        if block is None:
            out[m] = mine[0]
            continue
        first = np.array([entries[i]["blocks"][0] for i in mine])
        end = np.array([entries[i]["blocks"][1] for i in mine])
        j = np.floor(t[m] / block).astype(int)
        after = np.minimum(np.searchsorted(end, j, side="right"), len(mine) - 1)
        before = np.maximum(after - 1, 0)
        to_after, to_before = np.maximum(first[after] - j, 0), np.maximum(j - (end[before] - 1), 0)
        out[m] = mine[np.where(to_after <= to_before, after, before)]
    return out


# -- models per stretch: a recording they have not seen (new_data.fit) -------------------------------
def blocks_of(demo, t, length):
    """(block of each sample (N,), table (B, 2) [demonstration, j]) for blocks of ``length`` s
    (None: one per demonstration), sorted by demonstration, then time."""
    j = np.zeros(len(demo), int) if length is None else np.floor(t / length).astype(int)
    table, of = np.unique(np.stack([demo, j], 1), axis=0, return_inverse=True)
    return of.ravel(), table


def moments(U, of, n):
    """Σ u uᵀ of the samples of each block (n, q, q) and their counts (n,)."""
    S = np.zeros((n, U.shape[1], U.shape[1]))
    np.add.at(S, of, U[:, :, None] * U[:, None, :])
    return S, np.bincount(of, minlength=n)


def window_rows(U, of, n, fit):
    """The k rows of each window: the eigenvectors with the smallest eigenvalues of
    Σ u uᵀ + ρ n_w C̄, C̄ = UᵀU / N: (n, k, q)."""
    S, counts = moments(U, of, n)
    C = S + fit["shrinkage"] * counts[:, None, None] * (U.T @ U / len(U))
    return np.swapaxes(np.linalg.eigh(C)[1], 1, 2)[:, : fit["k"]]


def segments(fit, U, demo, t):
    """The segment of each sample (N,) and their number: blocks of each demonstration cut where
    Σ λ₁(C_segment) + β · segments is least (dynamic programming)."""
    of, table = blocks_of(demo, t, fit["block"])
    S, counts = moments(U, of, len(table))
    prior = fit["shrinkage"] * (U.T @ U / len(U))
    C = S + counts[:, None, None] * prior
    lam = np.linalg.eigvalsh(C)[:, 0]
    same = table[1:, 0] == table[:-1, 0]
    price = float(np.median(np.linalg.eigvalsh(C[1:][same] + C[:-1][same])[:, 0] - lam[1:][same]
                            - lam[:-1][same])) if same.any() else 0.0
    longest = max(1, int(np.floor(fit["window"] / fit["block"] + 1e-9)))
    segment, count = np.empty(len(table), int), 0
    for d in np.unique(table[:, 0]):
        mine = np.flatnonzero(table[:, 0] == d)
        beta = fit["penalty"] * price * np.log(max(len(mine), 2.0))
        P = np.concatenate([np.zeros((1, *S.shape[1:])), np.cumsum(S[mine], 0)])
        M = np.r_[0.0, np.cumsum(counts[mine].astype(float))]
        best, start = np.zeros(len(mine) + 1), np.zeros(len(mine) + 1, int)
        for j in range(1, len(mine) + 1):
            i = np.arange(max(0, j - longest), j)
            C = P[j] - P[i] + (M[j] - M[i])[:, None, None] * prior  # each candidate segment [i, j)
            total = best[i] + np.linalg.eigvalsh(C)[:, 0] + beta
            best[j], start[j] = total.min(), i[np.argmin(total)]
        cuts, j = [], len(mine)
        while j > 0:
            cuts.append((start[j], j))
            j = start[j]
        for i, j in reversed(cuts):
            segment[mine[i:j]] = count
            count += 1
    return segment[of], count


def white_noise(Y, demo, dirs, mad):
    """Variance of white noise on Y (N, d) along unit ``dirs`` (m, d): (median|Δ²y| / mad)² / 6."""
    inside = (demo[2:] == demo[1:-1]) & (demo[1:-1] == demo[:-2])
    d2 = (Y[2:] - 2 * Y[1:-1] + Y[:-2])[inside] @ dirs.T
    return (np.median(np.abs(d2), axis=0) / mad) ** 2 / 6 if len(d2) else np.zeros(len(dirs))


def noise_covariance(noise, X, U, demo, t):
    """Σ (q, q), the actions' noise covariance, from the robust variances along the axes and
    their diagonals (e_i + e_j)/√2 — at least the derived-velocity noise of the positions when
    the states are the positions (X has q columns)."""
    q = U.shape[1]
    i, j = np.triu_indices(q, 1)
    diag = np.zeros((len(i), q))
    diag[np.arange(len(i)), i] = diag[np.arange(len(i)), j] = np.sqrt(0.5)
    dirs = np.r_[np.eye(q), diag]
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    var = white_noise(U, demo, dirs, noise["mad_normal"])
    dt = np.diff(t)[demo[1:] == demo[:-1]]
    dt = float(np.median(dt[dt > 0])) if (dt > 0).any() else 0.0
    if X.shape[1] == q and dt > 0:
        order = noise["derivative_order"]
        half = int(round(noise["derivative_half_span"] / dt))
        window = min(max(2 * half + 1, order + 2 + (order + 3) % 2), noise["derivative_max_window"])
        k = np.arange(window) - window // 2
        c = np.linalg.pinv((k[:, None] * dt) ** np.arange(order + 1)[None, :])[1]
        var = np.maximum(var, white_noise(X, demo, dirs, noise["mad_normal"]) * float((c**2).sum()))
    Sigma = np.diag(var[:q])
    Sigma[i, j] = Sigma[j, i] = var[q:] - (var[i] + var[j]) / 2
    return Sigma


def classify(body, fit, X, U, demo, t):
    """Whether the rows hold at each sample of a new recording (N,): in the blocks that move
    above the noise and where the motion along every row is quiet; a still block takes the
    label of the nearest moving block before it in its demonstration, else after it."""
    R = np.asarray(body["rows"])
    of, table = blocks_of(demo, t, fit["block"])
    S, counts = moments(U, of, len(table))
    C = S / np.maximum(counts, 1)[:, None, None]
    Sigma = noise_covariance(fit["noise"], X, U, demo, t)
    total = np.trace(C, axis1=1, axis2=2)
    moving = total > fit["margin"] * np.trace(Sigma)
    typical = float(np.median(total[moving])) if moving.any() else 0.0
    energy = np.einsum("kq,bqr,kr->bk", R, C, R)
    noise = np.einsum("kq,qr,kr->k", R, Sigma, R)
    quiet = (energy <= fit["margin"] * noise) | (energy <= fit["share_block"] * typical)
    holds = quiet.all(1) & moving
    B, idx, d = len(table), np.arange(len(table)), table[:, 0]
    prev = np.maximum.accumulate(np.where(moving, idx, -1))
    nxt = np.minimum.accumulate(np.where(moving, idx, B)[::-1])[::-1]
    ok_prev = (prev >= 0) & (d[np.clip(prev, 0, B - 1)] == d)
    ok_next = (nxt < B) & (d[np.clip(nxt, 0, B - 1)] == d)
    src = np.where(ok_prev, prev, np.where(ok_next, nxt, -1))
    label = np.where(moving, holds, np.where(src >= 0, holds[np.clip(src, 0, B - 1)], False))
    return label[of]


def refit(fit, X, U):
    """A new demonstration's own model (new_data.fit of a per_demonstration model), as an entry's
    constraint: nhat — the k eigenvectors of UᵀU with the smallest eigenvalues; manifold — the
    level functions of its states (min tr WᵀCW subject to WᵀGW = I, by Cholesky)."""
    if fit["method"] == "nhat":
        rows = np.linalg.eigh(U.T @ U)[1].T[: fit["k"]]
        return {"form": "constant", "rows": rows, "projection": "orthonormal"}
    centre = X.mean(0)
    scale = float(np.sqrt(((X - centre) ** 2).sum(1).mean()))
    Phi, J = manifold_features(fit["basis"], (X - centre) / scale)
    D = Phi - Phi.sum(0) / len(Phi)
    C = D.T @ D / len(Phi)
    G = np.einsum("nfq,ngq->fg", J, J) / len(Phi)
    G += fit["ridge"] * np.trace(G) / len(G) * np.eye(len(G))
    Li = np.linalg.inv(np.linalg.cholesky(G))
    W = Li.T @ np.linalg.eigh(Li @ C @ Li.T)[1]
    return {"form": "manifold", "basis": fit["basis"], "centre": centre, "scale": scale,
            "levels": W[:, : fit["k"]].T, "projection": "orthonormal"}


# -- what a model predicts -------------------------------------------------------------------------
def projection(doc, X, demo=None, t=None, U=None, new_recording=True):
    """N(x) (N, q, q) of a constraint export at the samples of a recording: states X (N, p) and,
    for a model per stretch, the samples' demonstrations ``demo`` (N,), times ``t`` (N,) s and
    actions U (N, q). ``new_recording``: a recording the model has not seen (its new_data rule
    applies); False: held-out samples of the demonstrations it was fitted on (their entries)."""
    body, fit, q = doc["constraint"], doc["new_data"].get("fit"), doc["action"]["dimension"]
    if new_recording and not doc["new_data"]["reproducible"]:
        raise ValueError(f"this export's rule for a new recording needs ccl: {fit['why']}")
    X = np.asarray(X, float)
    demo = np.zeros(len(X), int) if demo is None else np.asarray(demo).astype(int)
    t = None if t is None else np.asarray(t, float)
    form = body["form"]
    if form == "windows":
        if not new_recording:
            A = np.asarray([e["rows"] for e in body["entries"]]).reshape(len(body["entries"]), -1, q)
            return projection_of(A[entry_of(body["entries"], body["block"], demo, t)], "orthonormal", q)
        if fit["method"] == "segments":
            of, n = segments(fit, U, demo, t)
        else:
            of, table = blocks_of(demo, t, fit["window"])
            n = len(table)
        return projection_of(window_rows(U, of, n, fit)[of], "orthonormal", q)
    if form == "manifold_phases":
        return projection_of(phase_rows(body, X, demo), "orthonormal", q)
    if form == "stretches":
        if new_recording:
            on = classify(body, fit, X, U, demo, t)
        else:
            phases = body["phases"]
            on = np.array([p["holds"] for p in phases])[entry_of(phases, body["block"], demo, t)]
        A = np.where(on[:, None, None], np.asarray(body["rows"])[None], 0.0)
        return projection_of(A, "orthonormal", q)
    if form == "per_demonstration":
        N = np.empty((len(X), q, q))
        for d in np.unique(demo):
            m = demo == d
            if new_recording:
                sub = refit(fit, X[m], np.asarray(U, float)[m])
            else:
                sub = body["entries"][entry_of(body["entries"], None, np.array([d]), None)[0]]["constraint"]
            N[m] = projection_of(rows_of(sub, X[m], q), sub["projection"], q)
        return N
    return projection_of(rows_of(body, X, q), body["projection"], q)


def nullspace(doc, X):
    """w(x) = W β(x) of a null-space export: (N, q)."""
    body = doc["nullspace"]
    return features(body["basis"], np.asarray(X, float)) @ np.asarray(body["weights"]).T


def policy(doc, X):
    """π(x) of a policy export: (N, q)."""
    body, X = doc["policy"], np.asarray(X, float)
    B, W = features(body["basis"], X), np.asarray(body["weights"])
    if body["form"] == "lwpi":
        return np.einsum("nc,ciq,ni->nq", B, W, np.hstack([X, np.ones((len(X), 1))]))
    return B @ W


# ---- end of the reference evaluator ----------------------------------------------------------------


def ccl(*args) -> tuple[int, str]:
    """``ccl ARGS`` in this process: (exit code, stdout)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([str(a) for a in args])
    return code, out.getvalue()


def write_yaml(path: Path, value: dict) -> Path:
    path.write_text(yaml.safe_dump(value))
    return path


def saddle(path: Path, seed: int) -> Path:
    """Positions scribbled over a saddle z = 1.5 (x² − y²) + 0.3 (m) at 50 Hz, six strokes of 8 s
    in one CSV (t, x, y, z): the manifold of a quadric."""
    rng = np.random.default_rng(seed)
    rows, start = [], 0.0
    for _ in range(6):
        t = np.arange(0, 8, 0.02)
        a, b = rng.uniform(0.5, 1.5, 2)
        x, y = 0.2 * np.sin(a * t + rng.uniform(0, 6)), 0.2 * np.sin(b * t + rng.uniform(0, 6))
        P = np.c_[x, y, 1.5 * (x**2 - y**2) + 0.3] + rng.normal(scale=2e-4, size=(len(t), 3))
        rows.append(np.c_[t + start, P])
        start += 18.0
    np.savetxt(path, np.vstack(rows), delimiter=",", header="t,x,y,z", comments="")
    return path


#: Recordings made by ``ccl simulate``: problem and options (seed 1 to learn from, 2 a new recording).
SIMULATED = {
    "sphere": ("tracker_sphere", "--duration", 15, "--n-recordings", 3),
    "plane": ("tracker_plane", "--duration", 15, "--n-recordings", 3),
    "wipe": ("arm_wipe", "--n-demos", 4),
    "varying": ("varying_constraint", "--n-demos", 20),
    "free": ("free_reach", "--n-demos", 3),
    "parabola": ("toy2d", "--constraint", "parabola", "--n-demos", 24),
    "parabola_task": ("toy2d", "--constraint", "parabola", "--n-demos", 12, "--task"),
    "two_link": ("two_link", "--n-demos", 12, "--n-steps", 20),
    "arm7": ("arm7", "--constraint", "jacobian", "--n-demos", 6),
    "tilt": ("tracker_tilt", "--duration", 36),
    "toy2d": ("toy2d", "--n-demos", 12),
    "toy2d_task": ("toy2d", "--task", "--sampling", "uniform", "--n-samples", 1000, "--n-demos", 10),
}
#: Headerless position logs of the shipped articulation recordings (a 10 Hz rate assumed).
LOGS = {"data": {"state": {"columns": [0, 1, 2], "units": "m"}, "action": {"derive": "state"},
                 "time": {"rate": 10}}}
SADDLE = {"data": {"time": {"column": "t"}, "state": {"columns": ["x", "y", "z"], "units": "m"},
                   "action": {"derive": "state"}}}

#: name, recordings, learn-a settings, the method the model file holds, k. ``auto`` first: what it
#: chooses on each (manifold sphere and quadric, nhat, in stretches, per demonstration, none, one
#: manifold per demonstration), then the explicit methods.
CONSTRAINTS = [
    ("sphere", "sphere", {}, "manifold", 1),
    ("plane", "plane", {}, "nhat", 1),
    ("wipe", "wipe", {}, "manifold_phases", 1),
    ("stretches", "wipe", {"candidates": ["nhat", "per_demo", "stretches"]}, "stretches", 1),
    ("varying", "varying", {}, "per_demo:manifold", 1),
    ("free", "free", {}, "none", 0),
    ("saddle", "saddle", {}, "manifold", 1),
    ("drawer", "drawer", {}, "nhat", 2),
    ("dishwasher", "dishwasher", {}, "per_demo:manifold", 2),
    ("alpha", "parabola", {"method": "alpha", "tune": False}, "alpha", 1),
    ("alpha_linear", "parabola", {"method": "alpha", "tune": False, "basis": "linear"}, "alpha", 1),
    ("lambda_arm2", "two_link", {"method": "lambda", "features": "arm2", "tune": False, "n_restarts": 1},
     "lambda", 1),
    ("lambda_arm7", "arm7", {"method": "lambda", "features": {"arm": "arm7", "rows": [0, 1, 2]},
                             "tune": False, "n_restarts": 1, "n_centres": 9}, "lambda", 2),
    ("linear", "parabola", {"method": "linear", "regressors": "polynomial", "degree": 2, "tune": False},
     "linear", 1),
    ("linear_task", "parabola_task", {"method": "linear", "regressors": "rbf", "task": True,
                                      "task_regressors": "polynomial", "tune": False}, "linear", 1),
    ("per_window", "tilt", {"method": "per_window", "window": 6.0}, "per_window", 1),
    ("per_segment", "tilt", {"method": "per_segment"}, "per_segment", 1),
    ("per_demo_nhat", "varying", {"method": "nhat", "per_demo": True, "n_constraints": 1},
     "per_demo:nhat", 1),
]
#: name, recordings, stage, settings, what ``predict`` writes.
OTHERS = [
    ("ncl", "toy2d_task", "learn-v", {"tune": False}, "w"),
    ("pi", "toy2d", "learn-pi", {"method": "pi", "tune": False}, "pi"),
    ("lwpi", "toy2d", "learn-pi", {"method": "lwpi", "tune": False}, "pi"),
]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Recordings made on first use (to learn from, and new ones) and models learnt on first use."""
    root = tmp_path_factory.mktemp("export")
    made: dict = {}

    def recordings(name: str) -> tuple[list[Path], list[Path], dict]:
        """(files to learn from, a new recording's files, the data section of the config)."""
        if name in made:
            return made[name]
        if name == "lwr":  # a robot's joint log, states by forward kinematics (configs/lwr_wipe_fk.yaml)
            lwr = yaml.safe_load((ROOT / "configs" / "lwr_wipe_fk.yaml").read_text())["data"]
            lwr["state"]["forward_kinematics"]["robot"] = str(ROOT / "sample_data" / "lwr4.urdf")
            del lwr["files"]
            made[name] = ([ROOT / "sample_data" / "lwr_wipe.mat"], [ROOT / "sample_data" / "lwr_wipe.mat"],
                          {"data": lwr})
        elif name in ("drawer", "dishwasher"):
            logs = sorted((ARTICULATION / name).glob("*.log"))
            made[name] = (logs[:6], logs[6:], LOGS)
        elif name == "saddle":
            made[name] = ([saddle(root / "saddle1.csv", 1)], [saddle(root / "saddle2.csv", 2)], SADDLE)
        else:
            problem, *options = SIMULATED[name]
            files = []
            for seed in (1, 2):
                path = root / f"{name}{seed}.h5"
                assert ccl("simulate", problem, *options, "--seed", seed, "-o", path, "-q")[0] == 0
                files.append([path])
            made[name] = (*files, {})
        return made[name]

    def learnt(name: str, data: str, stage: str, settings: dict) -> dict:
        """The model learnt by ``ccl STAGE`` on ``data``, exported to YAML and JSON, and ``ccl predict``
        of it on the new recording and on the recordings it was learnt from."""
        key = ("model", name)
        if key in made:
            return made[key]
        train, new, section = recordings(data)
        out = root / name
        config = {**section, "output": {"plots": False}, stage: settings}
        cfg = write_yaml(root / f"{name}-config.yaml", config)
        assert ccl(stage, *train, "-c", cfg, "-o", out, "-q")[0] == 0
        model = out / "model.h5"
        for suffix in ("yaml", "json"):
            assert ccl("export", model, "-o", root / f"{name}.{suffix}", "-q")[0] == 0
        for part, files in (("new", new), ("seen", train)):
            assert ccl("predict", model, *files, "-c", cfg, "-o", root / f"{name}-{part}.h5", "-q")[0] == 0
        made[key] = {"model": model, "yaml": root / f"{name}.yaml", "json": root / f"{name}.json",
                     "new": root / f"{name}-new.h5", "seen": root / f"{name}-seen.h5", "config": cfg}
        return made[key]

    return learnt


def predictions(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f[k][()] for k in f}


@pytest.mark.parametrize("case", CONSTRAINTS, ids=[c[0] for c in CONSTRAINTS])
def test_exported_constraint_equals_ccl_predict_on_a_new_recording(case, work):
    name, data, settings, method, k = case
    m = work(name, data, "learn-a", settings)
    doc = load(m["yaml"])
    assert doc == load(m["json"])  # YAML and JSON: the same document, every number read back alike
    assert (doc["kind"], doc["method"], doc["k"]) == ("constraint", method, k)
    p = predictions(m["new"])
    N = projection(doc, p["x"], p["demo"], p["t"], p["u"])
    assert N.shape == p["N"].shape
    assert np.abs(N - p["N"]).max() <= TOL
    q = doc["action"]["dimension"]  # and N is a projection of rank q − k (q where a stretch does not hold)
    rank = np.trace(N, axis1=1, axis2=2)
    assert np.abs(N @ N - N).max() < 1e-9
    in_parts = doc["scope"] == "stretch" or doc["constraint"]["form"] == "manifold_phases"
    assert np.all((np.abs(rank - (q - k)) < 1e-9) | (in_parts & (np.abs(rank - q) < 1e-9)))
    if doc["constraint"]["form"] == "manifold_phases":  # both branches of its rule are compared
        assert 0.1 < np.mean(np.abs(rank - (q - k)) < 1e-9) < 0.9


LOCAL = [c for c in CONSTRAINTS if c[0] in ("stretches", "varying", "dishwasher", "per_window", "per_segment",
                                                "per_demo_nhat")]


@pytest.mark.parametrize("case", LOCAL, ids=[c[0] for c in LOCAL])
def test_a_model_per_stretch_gives_its_entries_on_the_demonstrations_it_was_fitted_on(case, work):
    """The lookup of each sample's entry (window, segment, phase, demonstration — the nearest one
    for a stretch held out of training) against the loaded model's own projection."""
    from ccl_cli.models import load_model

    name, data, settings, *_ = case
    m = work(name, data, "learn-a", settings)
    doc, p = load(m["yaml"]), predictions(m["seen"])
    body = doc["constraint"]
    seen = np.isin(p["demo"], [e["demonstration"] for e in body.get("entries") or body["phases"]])
    x, demo, t, u = p["x"][seen], p["demo"][seen], p["t"][seen], p["u"][seen]
    assert seen.sum() >= 100
    model, _ = load_model(m["model"])
    N = projection(doc, x, demo, t, u, new_recording=False)
    assert np.abs(N - model.projection(x, groups=demo, t=t)).max() <= TOL


@pytest.mark.parametrize("case", OTHERS, ids=[c[0] for c in OTHERS])
def test_exported_nullspace_and_policy_equal_ccl_predict_on_a_new_recording(case, work):
    name, data, stage, settings, key = case
    m = work(name, data, stage, settings)
    doc = load(m["yaml"])
    assert doc == load(m["json"])
    p = predictions(m["new"])
    mine = nullspace(doc, p["x"]) if key == "w" else policy(doc, p["x"])
    assert np.abs(p[key]).max() > 1e-3  # the comparison is not of zeros
    assert np.abs(mine - p[key]).max() <= TOL


def test_the_task_part_of_a_linear_model_with_a_task_term(work):
    from ccl_cli.models import load_model

    name, data, settings, *_ = next(c for c in CONSTRAINTS if c[0] == "linear_task")
    m = work(name, data, "learn-a", settings)
    doc, p = load(m["yaml"]), predictions(m["new"])
    model, _ = load_model(m["model"])
    v = model.task_part(p["x"])
    assert np.abs(v).max() > 1e-3
    assert np.abs(task_part(doc, p["x"]) - v).max() <= TOL


def test_constant_rows_are_read_from_three_keys_exactly_as_saved(work):
    """The real drawer (a slide): k = 2 constant rows at the top level — the model file's own
    doubles, orthonormal, across the slide — with the data's names and units and the provenance."""
    m = work("drawer", "drawer", "learn-a", {})
    doc = yaml.safe_load(m["yaml"].read_text())
    with h5py.File(m["model"], "r") as f:
        saved = f["arrays/A_"][()]
    rows = np.array(doc["rows"])
    assert doc["k"] == 2 and doc["scope"] == "global" and doc["frame"] is None
    assert np.array_equal(rows, saved) and np.array_equal(rows, np.array(doc["constraint"]["rows"]))
    assert np.abs(rows @ rows.T - np.eye(2)).max() < 1e-12
    assert doc["state"]["units"] == ["m"] * 3 and doc["action"]["units"] == ["m/s"] * 3
    inputs = doc["training"]["inputs"]
    assert len(inputs) == 6 and all(re.fullmatch("[0-9a-f]{64}", h) for h in inputs.values())
    assert doc["training"]["versions"]["numpy"] == np.__version__
    assert re.fullmatch("[0-9a-f]{64}", doc["source"]["sha256"])


def test_a_hinge_per_demonstration_is_one_circle_each(work):
    """The real dishwasher door: per demonstration two level functions of [z; ‖z‖²] whose rows are
    the door's axis and the radial direction, so Ñ is the tangent of the circle the hand follows:
    along the demonstrated velocities: 5 % of their energy is across it (derived at an assumed
    10 Hz from noisy positions), against 2/3 for a tangent drawn at random."""
    m = work("dishwasher", "dishwasher", "learn-a", {})
    doc, p = load(m["yaml"]), predictions(m["new"])
    body = doc["constraint"]
    assert body["form"] == "per_demonstration" and len(body["entries"]) >= 3
    assert all(e["constraint"]["basis"] == "sphere" and e["k"] == 2 for e in body["entries"])
    assert doc["new_data"]["reproducible"] and doc["new_data"]["fit"] == {
        "method": "manifold", "k": 2, "basis": "sphere", "ridge": 1e-9}
    N = projection(doc, p["x"], p["demo"], p["t"], p["u"])
    u, w = p["u"], np.einsum("nij,nj->ni", N, p["u"])
    assert np.sum((u - w) ** 2) / np.sum(u**2) < 0.1


def test_frame_names_and_a_rule_that_needs_ccl(work, tmp_path):
    """Task-space states by forward kinematics: the frame is the chain's base; one nhat per
    demonstration with its own rule for k cannot be fitted on a new recording from the file:
    the export says so, and the evaluator refuses rather than guess (its entries still evaluate)."""
    m = work("fk", "lwr", "learn-a", {"method": "nhat", "per_demo": True})
    doc = load(m["yaml"])
    assert doc["frame"] == "base" and doc["state"]["forward_kinematics"]["frame"] == "flange"
    assert doc["state"]["names"] == ["x", "y", "z"] and doc["state"]["units"] == ["m"] * 3
    assert doc["new_data"]["rule"] == "fitted per demonstration" and not doc["new_data"]["reproducible"]
    assert "ccl predict" in doc["new_data"]["fit"]["why"]
    p = predictions(m["new"])
    with pytest.raises(ValueError, match="needs ccl"):
        projection(doc, p["x"], p["demo"], p["t"], p["u"])


def test_the_docs_hold_the_evaluator_tested_here():
    """docs/export.md's reference evaluator is this file's copy, to the character."""
    doc = (ROOT / "docs" / "export.md").read_text(encoding="utf-8")
    block = doc.split("## Reference evaluator", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    header, body = block.split("\n\n\n", 1)
    assert header == "import json\n\nimport numpy as np\nimport yaml"
    here = Path(__file__).read_text(encoding="utf-8")
    copy = here.split("# ---- reference evaluator", 1)[1].split("\n", 1)[1]
    copy = copy.split("# ---- end of the reference evaluator", 1)[0]
    assert body.strip() == copy.strip()


# -- the command's conventions -------------------------------------------------------------------
def test_export_keeps_the_command_line_conventions(work, tmp_path, capsys):
    m = work("drawer", "drawer", "learn-a", {})
    model, out = m["model"], tmp_path / "rows.yaml"

    def run(*args):
        code = main([str(a) for a in args])
        got = capsys.readouterr()
        return code, got.out, got.err

    code, stdout, _ = run("export", model, "-o", out, "--json")
    summary = json.loads(stdout)
    assert code == 0 and summary["status"] == "ok" and (summary["k"], summary["form"]) == (2, "constant")
    assert (summary["schema_version"], summary["scope"], summary["new_data"]) == (1, "global", "as fitted")
    before = out.read_bytes()
    code, _, err = run("export", model, "-o", out)  # no overwrite without --force
    assert code == 2 and "--force" in err and len(err.strip().splitlines()) == 1
    assert out.read_bytes() == before
    assert run("export", model, "-o", out, "--force")[0] == 0 and load(out)["k"] == 2
    for bad, why in ((tmp_path / "rows.txt", ".yaml, .yml or .json"), (model, "end in")):
        code, _, err = run("export", model, "-o", bad)
        assert code == 2 and why in err and len(err.strip().splitlines()) == 1
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(model.read_bytes()[: model.stat().st_size // 2])
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 8)
    recording = tmp_path / "recording.h5"
    assert ccl("simulate", "toy2d", "--n-demos", 2, "-o", recording, "-q")[0] == 0
    for path in (damaged, garbage, recording, tmp_path / "missing.h5"):
        code, stdout, err = run("export", path, "-o", tmp_path / "x.json", "--json")
        assert code == 2 and err.startswith("ccl: error:") and len(err.strip().splitlines()) == 1
        assert json.loads(stdout)["status"] == "error" and "Traceback" not in err
        assert not (tmp_path / "x.json").exists()
    left = sorted(p.name for p in tmp_path.iterdir())  # nothing half-written, no temporaries
    assert left == ["damaged.h5", "garbage.h5", "recording.h5", "rows.yaml"]
    code, stdout, _ = run("export", "--help")
    assert code == 0 and "YAML" in stdout and "JSON" in stdout and "docs/export.md" in stdout
    code, _, err = run("export", model)
    assert code == 2 and "--out" in err
