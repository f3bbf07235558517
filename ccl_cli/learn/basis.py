"""Feature maps β(x) ∈ R^K (ALGORITHMS.md §2).

* :class:`RBFBasis` — normalised Gaussian RBF, β_k = g_k / Σ_j g_j with
  g_k = exp(−‖x − c_k‖² / (2σ²)), computed as a soft-max (the row-wise largest
  exponent is subtracted first) so points far from every centre never give 0/0.
* :class:`LinearBasis` — β(x) = [x; 1].

Centres come from a regular grid over the widened bounding box of the data or from
seeded k-means. The default width is σ² = (mean over all centre pairs, i = j
included, of ‖c_i − c_j‖)², as in the original library.
"""

from __future__ import annotations

import copy
import hashlib
from collections import OrderedDict
from collections.abc import Callable, Iterable
from typing import Annotated, Any, Literal

import numpy as np

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn.linalg import row_chunks
from ccl_cli.learn.params import BasisKind, Fields, Interval, Seed, out_of_range, parameters

#: Feature blocks of iterative learners are kept in memory up to this many bytes (N K · 8);
#: above it they are recomputed on every pass, so memory stays bounded in N.
FEATURE_CACHE_BYTES = 256 * 2**20
#: ... and above this multiple of the learner's input arrays (issue 19: peak memory ≤ 5× the
#: inputs), unless they take less than :data:`FEATURE_CACHE_FLOOR` bytes.
FEATURE_CACHE_RATIO = 3
FEATURE_CACHE_FLOOR = 64 * 2**20


def feature_cache_bytes(*inputs: np.ndarray) -> int:
    """Bytes of feature blocks a learner keeps between passes over its ``inputs`` (arrays):
    min(FEATURE_CACHE_BYTES, max(FEATURE_CACHE_FLOOR, FEATURE_CACHE_RATIO · their bytes))."""
    size = sum(int(np.asarray(a).nbytes) for a in inputs)
    return min(FEATURE_CACHE_BYTES, max(FEATURE_CACHE_FLOOR, FEATURE_CACHE_RATIO * size))


def pairwise_sqdist(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """‖a_i − b_j‖² for rows of A (N, p) and B (K, p) → (N, K), clipped at 0."""
    d = (A * A).sum(1)[:, None] - 2.0 * A @ B.T + (B * B).sum(1)[None, :]
    return np.maximum(d, 0.0)


def grid_centres(X: np.ndarray, n_centres: int, margin: float = 0.1) -> np.ndarray:
    """A regular grid of ``floor(K^(1/p))`` points per axis over the bounding box of X
    widened by ``margin`` on each side: (N, p) → (floor(K^(1/p))^p, p)."""
    X = np.asarray(X, dtype=float)
    p = X.shape[1]
    per_axis = max(1, int(np.floor(n_centres ** (1.0 / p) + 1e-9)))
    lo, hi = X.min(0) - margin, X.max(0) + margin
    axes = [np.linspace(lo[d], hi[d], per_axis) for d in range(p)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


#: k-means runs on a seeded subsample of at most max(KMEANS_SAMPLE, 50 K) rows (5000, not 20000:
#: the test errors of ncl, pi-weighted and alpha at N = 1e5 are the same within their spread
#: over training draws, at a quarter of the cost; docs/measurements.md, "k-means").
KMEANS_SAMPLE = 5_000


def cluster_sums(X: np.ndarray, label: np.ndarray, k: int) -> np.ndarray:
    """Σ of the rows of X (N, p) per label in 0..k−1 → (k, p) (bincount per column)."""
    return np.stack([np.bincount(label, weights=X[:, j], minlength=k) for j in range(X.shape[1])], 1)


def cluster_moments(Y: np.ndarray, label: np.ndarray, k: int) -> np.ndarray:
    """Σ y yᵀ of the rows of Y (N, q) per label in 0..k−1 → (k, q, q)."""
    q = Y.shape[1]
    return cluster_sums((Y[:, :, None] * Y[:, None, :]).reshape(len(Y), q * q), label, k).reshape(k, q, q)


#: The last k-means results, by a digest of the data and the settings (a search fits the
#: same centres for every width of a basis size, and its winner on all rows again).
_KMEANS_CACHE: OrderedDict[tuple, np.ndarray] = OrderedDict()
KMEANS_CACHE_ENTRIES = 32


def kmeans_centres(
    X: np.ndarray, n_centres: int, seed: int = 0, max_iter: int = 100, tol: float = 1e-6,
    max_samples: int | None = None,
) -> np.ndarray:
    """:func:`kmeans` of X (N, p) with these settings, remembered for the same data (a digest of
    its bytes) and settings: the same (K, p) centres, computed once."""
    X = np.ascontiguousarray(X, dtype=float)
    key = (hashlib.blake2b(X.view(np.uint8), digest_size=16).digest(), X.shape, int(n_centres), int(seed),
           int(max_iter), float(tol), max_samples)
    if key in _KMEANS_CACHE:
        _KMEANS_CACHE.move_to_end(key)
    else:
        _KMEANS_CACHE[key] = kmeans(X, n_centres, seed, max_iter, tol, max_samples)
        while len(_KMEANS_CACHE) > KMEANS_CACHE_ENTRIES:
            _KMEANS_CACHE.popitem(last=False)
    return _KMEANS_CACHE[key].copy()


def kmeans(
    X: np.ndarray, n_centres: int, seed: int = 0, max_iter: int = 100, tol: float = 1e-6,
    max_samples: int | None = None,
) -> np.ndarray:
    """Seeded k-means (k-means++ start, Lloyd iterations) on the rows of X (N, p) → (K, p).

    Large N: a seeded subsample of ``max_samples`` rows (default max(5000, 50 K)) is
    clustered, so the cost is independent of N. Lloyd stops when no label changes or the
    total squared centre shift Σ_k ‖Δc_k‖² falls below ``tol`` times the mean per-axis
    variance of the data (a relative tolerance, reached whatever the units; the rule of
    scikit-learn). An empty cluster is re-seeded with
    the point farthest from its assigned centre.
    """
    X = np.asarray(X, dtype=float)
    n = X.shape[0]
    if n < n_centres:
        raise InputError(f"k-means needs at least {n_centres} samples, got {n}")
    rng = np.random.default_rng(seed)
    limit = max_samples or max(KMEANS_SAMPLE, 50 * n_centres)
    if n > limit:
        X = X[np.sort(rng.choice(n, limit, replace=False))]
        n = limit
    spread = float(np.mean(np.var(X, axis=0)))
    centres = np.empty((n_centres, X.shape[1]))
    centres[0] = X[rng.integers(n)]
    closest = pairwise_sqdist(X, centres[:1])[:, 0]
    for k in range(1, n_centres):  # k-means++: loop over centres, not samples
        total = closest.sum()
        idx = rng.choice(n, p=closest / total) if total > 0 else rng.integers(n)
        centres[k] = X[idx]
        closest = np.minimum(closest, pairwise_sqdist(X, centres[k : k + 1])[:, 0])
    label = np.full(n, -1)
    for _ in range(max_iter):
        d2 = pairwise_sqdist(X, centres)
        new_label = d2.argmin(1)
        if np.array_equal(new_label, label):
            break
        label = new_label
        counts = np.bincount(label, minlength=n_centres)
        sums = cluster_sums(X, label, n_centres)
        new = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], centres)
        empty = np.flatnonzero(counts == 0)
        if empty.size:
            own = d2[np.arange(n), label]
            far = np.argsort(own)[::-1][: empty.size]
            new[empty] = X[far]
        shift = float(np.sum((new - centres) ** 2))
        centres = new
        if shift <= tol * spread and not empty.size:
            break
    return centres


def default_sigma2(centres: np.ndarray) -> float:
    """σ² = (mean_{i,j} ‖c_i − c_j‖)², pairs with i = j included."""
    dist = np.sqrt(pairwise_sqdist(centres, centres))
    value = float(dist.mean()) ** 2
    return value if value > 0 else 1.0


class RBFBasis:
    """Normalised Gaussian radial basis functions.

    Args:
        n_centres: K (with ``centres="grid"`` the grid has floor(K^(1/p))^p points).
        centres: ``"kmeans"`` or ``"grid"``, or an explicit (K, p) array.
        sigma2: squared width σ²; ``None`` uses the default rule.
        seed: seed of k-means.

    Attributes:
        centres_: (K, p). sigma2_: float.
    """

    kind = "rbf"

    def __init__(
        self,
        n_centres: int = 16,
        centres: str | np.ndarray = "kmeans",
        sigma2: float | None = None,
        seed: int = 0,
    ) -> None:
        self.n_centres = n_centres
        self.centres = centres
        self.sigma2 = sigma2
        self.seed = seed

    def fit(self, X: np.ndarray) -> RBFBasis:
        X = np.asarray(X, dtype=float)
        if isinstance(self.centres, str):
            if self.centres == "kmeans":
                self.centres_ = kmeans_centres(X, self.n_centres, seed=self.seed)
            elif self.centres == "grid":
                self.centres_ = grid_centres(X, self.n_centres)
            else:
                raise ConfigError(f"unknown centre placement {self.centres!r} (use kmeans or grid)")
        else:
            self.centres_ = np.asarray(self.centres, dtype=float)
            if self.centres_.ndim != 2 or self.centres_.shape[1] != X.shape[1]:
                raise ConfigError(f"centres must be (K, {X.shape[1]}), got {self.centres_.shape}")
        if self.sigma2 is not None and not self.sigma2 > 0:
            raise ConfigError(out_of_range("sigma2", self.sigma2, Interval(0, None, closed="neither")))
        self.sigma2_ = float(self.sigma2) if self.sigma2 is not None else default_sigma2(self.centres_)
        return self

    @property
    def n_features(self) -> int:
        return int(self.centres_.shape[0])

    @property
    def n_state(self) -> int:
        """p, the state dimension of the centres."""
        return int(self.centres_.shape[1])

    def transform(self, X: np.ndarray) -> np.ndarray:
        """β(X): (N, p) → (N, K); rows sum to 1."""
        logits = -pairwise_sqdist(np.asarray(X, dtype=float), self.centres_) / (2.0 * self.sigma2_)
        logits -= logits.max(axis=1, keepdims=True)
        g = np.exp(logits)
        return g / g.sum(axis=1, keepdims=True)

    def unnormalised(self, X: np.ndarray) -> np.ndarray:
        """g(X) (N, K) without normalisation (weights of locally weighted models)."""
        return np.exp(-pairwise_sqdist(np.asarray(X, dtype=float), self.centres_) / (2.0 * self.sigma2_))

    def state(self) -> dict[str, Any]:
        return {"kind": self.kind, "centres": self.centres_, "sigma2": self.sigma2_}


class LinearBasis:
    """β(x) = [x; 1] (K = p + 1)."""

    kind = "linear"

    def fit(self, X: np.ndarray) -> LinearBasis:
        self.n_state_ = int(np.asarray(X).shape[1])
        return self

    @property
    def n_features(self) -> int:
        return self.n_state_ + 1

    @property
    def n_state(self) -> int:
        return int(self.n_state_)

    def transform(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        return np.hstack([X, np.ones((X.shape[0], 1))])

    def state(self) -> dict[str, Any]:
        return {"kind": self.kind, "n_state": self.n_state_}


Basis = RBFBasis | LinearBasis
#: RBF centres.
NCentres = Annotated[int, Interval(1, 100_000)]
#: The keys of a ``basis`` mapping (a linear basis takes none but ``kind``).
BASIS_FIELDS = Fields(kind=BasisKind, n_centres=NCentres,
                      centres=Literal["kmeans", "grid"] | list | np.ndarray,
                      sigma2=Annotated[float, Interval(1e-300, None)], seed=Seed)
#: What a learner's ``basis`` parameter takes: a kind, a mapping, a basis object or None (rbf).
BasisSpec = BasisKind | Annotated[dict, BASIS_FIELDS] | RBFBasis | LinearBasis | None


@parameters
class BasisParams:
    """``basis``: the feature map (``"rbf"``, ``"linear"``, a mapping ``{kind, n_centres,
    centres, sigma2, seed}`` or a basis object); ``n_centres``: RBF centres when it is a name."""

    basis: BasisSpec = "rbf"
    n_centres: NCentres = 16


def make_basis(spec: BasisSpec, default_centres: int = 16, seed: int = 0) -> Basis:
    """A new, unfitted basis from a parameter value: ``"rbf"``, ``"linear"``, a dict
    ``{kind, n_centres, centres, sigma2, seed}``, or a basis object (copied: fitting never
    changes the object given)."""
    if spec is None:
        spec = "rbf"
    if isinstance(spec, RBFBasis | LinearBasis):
        return copy.deepcopy(spec)
    if isinstance(spec, str):
        spec = {"kind": spec}
    spec = dict(spec)
    kind = spec.pop("kind", "rbf")
    if kind == "linear":
        if spec:
            raise ConfigError(f"linear basis takes no options, got {sorted(spec)}")
        return LinearBasis()
    if kind == "rbf":
        unknown = set(spec) - {"n_centres", "centres", "sigma2", "seed"}
        if unknown:
            raise ConfigError(f"unknown rbf basis option(s): {', '.join(sorted(unknown))}")
        return RBFBasis(
            n_centres=int(spec.get("n_centres", default_centres)),
            centres=spec.get("centres", "kmeans"),
            sigma2=spec.get("sigma2"),
            seed=int(spec.get("seed", seed)),
        )
    raise ConfigError(f"unknown basis kind {kind!r} (use rbf or linear)")


#: A re-iterable source of (rows, β(X[rows])) blocks (:func:`feature_blocks`).
Blocks = Callable[[], Iterable[tuple[slice, np.ndarray]]]


def feature_blocks(basis: Basis, X: np.ndarray, chunk_size: int | None = None,
                   cache_bytes: int = FEATURE_CACHE_BYTES) -> Blocks:
    """A re-iterable source of (rows, β(X[rows]) (c, K)) blocks for chunked passes.

    The blocks are computed once and kept when N K floats fit in ``cache_bytes``,
    otherwise recomputed on each pass (memory O(chunk_size · K), independent of N).
    """
    slices = row_chunks(len(X), chunk_size)
    if len(X) * basis.n_features * 8 <= cache_bytes:
        cached = [(s, basis.transform(X[s])) for s in slices]
        return lambda: cached
    return lambda: ((s, basis.transform(X[s])) for s in slices)


def basis_from_state(state: dict[str, Any]) -> Basis:
    """Rebuild a fitted basis from :meth:`state` (used when loading models)."""
    if state["kind"] == "linear":
        b = LinearBasis()
        b.n_state_ = int(state["n_state"])
        return b
    if state["kind"] == "rbf":
        b = RBFBasis(n_centres=int(np.shape(state["centres"])[0]))
        b.centres_ = np.asarray(state["centres"], dtype=float)
        b.sigma2_ = float(state["sigma2"])
        return b
    raise InputError(f"unknown basis kind {state['kind']!r} in model file")
