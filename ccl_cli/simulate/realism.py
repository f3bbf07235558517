"""What real recordings add to an ideal constrained motion (issue 30), shared by the mechanism,
contact and free-motion simulations (:mod:`.mechanisms`, :mod:`.contact`, :mod:`.free`).

Real rows sit well above white sensor noise: the contact gives, hands tremble, sensors drift
and velocities are filtered. Each effect here is a function of continuous time (a sum of
sinusoids with seeded frequencies and phases, per demonstration), so a simulation sampled at
another rate draws the same motion, and its derivative is exact:

* **compliance** — motion along the constraint rows, low-pass (frequencies uniform in
  ``band``, 0.1–1 Hz by default), RMS ``std`` m: a door that flexes, a drawer that rattles in
  its rail, a finger pad pressing into a surface. On the TUM hinge and drawer logs the
  motion across the fitted circle or line is 0.6–6 mm RMS, of which 0.35–1.1 mm is white
  (second differences); the rest stays correlated over 5–20 samples (1–4 cm of travel).
* **tremor** — a hand's physiological tremor, 8–12 Hz in every direction, RMS ``std`` m (a
  Trakstar on a fingertip: ~0.4–0.7 mm, velocities of ~0.02 m/s in that band).
* **drift** — the sensor's reading walks off at ``drift`` m/s along a seeded direction per
  demonstration (a magnetic tracker warming up, a calibration creeping).
* **white noise** of std ``noise`` m on the recorded positions.
* **velocities** ``derived`` (the readers' local polynomial at the rate's default window:
  what ccl does with positions) or ``filtered`` (recorded by the device: a first-order
  low-pass at ``filter_hz`` of the backward difference, with its lag — the "smoothed
  velocity" many logs carry).

Each effect draws from a random stream of its own (seed, tag), so switching one on or off does
not change the others or the ideal path.

Ground truth (:func:`constrained_truth`): of the true velocity ẋ (ideal path + compliance +
tremor: what the hand really did; drift and noise are the sensor's), with orthonormal rows
A (N, k, q) at each sample, b = Aẋ, v = Aᵀb, w = π = ẋ − v, N = I − AᵀA.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, Derivative
from ccl_cli.errors import ConfigError
from ccl_cli.learn.linalg import unit_rows
from ccl_cli.simulate.recordings import derive

#: Stream tags of the effects (the second word of each random stream's seed).
STREAMS = {"path": 0, "compliance": 1, "tremor": 2, "drift": 3, "noise": 4, "frame": 5}
#: Band (Hz) of a hand's physiological tremor.
TREMOR_HZ = (8.0, 12.0)
#: Sinusoids per band-limited signal (enough for a Gaussian-looking signal).
TERMS = 24
#: Half step (s) of the central difference giving a path's true velocity.
STEP_S = 1e-6
#: The ways the actions are made (module docstring).
VELOCITIES = ("derived", "filtered")


def stream(seed: int, name: str) -> np.random.Generator:
    """The random stream of one effect (:data:`STREAMS`) for ``seed``."""
    return np.random.default_rng([int(seed), STREAMS[name]])


@dataclass(frozen=True)
class Band:
    """A random signal s(t) per demonstration and channel: TERMS sinusoids of amplitude
    ``amplitude`` each, frequencies ``freq`` (D, c, K) Hz and phases ``phase`` (D, c, K)."""

    freq: np.ndarray
    phase: np.ndarray
    amplitude: float

    @classmethod
    def draw(cls, rng: np.random.Generator, n_demos: int, channels: int, std: float,
             band: tuple[float, float]) -> Band:
        """RMS ``std`` per channel (amplitude std·√(2/TERMS)), frequencies uniform in ``band``
        (Hz), phases uniform."""
        f = rng.uniform(*band, (n_demos, channels, TERMS))
        return cls(f, rng.uniform(0.0, 2 * np.pi, f.shape), float(std) * np.sqrt(2.0 / TERMS))

    def at(self, t: np.ndarray, demo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """s(t) and ṡ(t) (N, c) at times t (N,) s of demonstrations demo (N,)."""
        if self.amplitude == 0:
            zeros = np.zeros((len(t), self.freq.shape[1]))
            return zeros, zeros.copy()
        omega = 2 * np.pi * self.freq[demo]  # (N, c, K)
        arg = omega * t[:, None, None] + self.phase[demo]
        return self.amplitude * np.sin(arg).sum(-1), self.amplitude * (omega * np.cos(arg)).sum(-1)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation (3, 3) drawn uniformly (QR of a Gaussian matrix, signs fixed, det +1)."""
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0:
        Q[:, 0] = -Q[:, 0]
    return Q


def check(name: str, value: Any, ok: bool, what: str) -> None:
    """ConfigError ``{name} … must be {what}`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"{name} must be {what}, got {value!r}")


def check_effects(*, noise: float, compliance: float, tremor: float, drift: float, rate: float,
                  velocities: str, filter_hz: float, band: tuple[float, float]) -> None:
    """One ConfigError for the first effect out of range (module docstring)."""
    for name, value in (("noise", noise), ("compliance", compliance), ("tremor", tremor), ("drift", drift)):
        check(name, value, np.isfinite(value) and value >= 0, "a finite number ≥ 0 (m or m/s)")
    check("rate", rate, np.isfinite(rate) and 1.0 <= rate <= 10_000.0, "1–10000 Hz")
    check("velocities", velocities, velocities in VELOCITIES, f"one of {', '.join(VELOCITIES)}")
    check("filter_hz", filter_hz, np.isfinite(filter_hz) and 0 < filter_hz, "a frequency > 0 Hz")
    check("compliance_hz", band, len(band) == 2 and 0 < band[0] <= band[1], "a band (low, high) > 0 Hz")


def sampled(durations: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Stamps t (N,) from 0 within each demonstration of ``durations`` (D,) s at ``rate`` Hz, and
    the demonstration of each sample (at least 20 samples each)."""
    counts = np.maximum(np.round(np.asarray(durations) * rate).astype(int), 20)
    demo = np.repeat(np.arange(len(counts)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    return (np.arange(counts.sum()) - first) / rate, demo


def tremor_band(seed: int, n_demos: int, q: int, std: float) -> Band:
    """A hand's tremor in every one of q directions (:data:`TREMOR_HZ`, RMS ``std`` m)."""
    return Band.draw(stream(seed, "tremor"), n_demos, q, std, TREMOR_HZ)


def compliance_band(seed: int, n_demos: int, k: int, std: float, band: tuple[float, float]) -> Band:
    """Motion along k constraint rows (``band`` Hz, RMS ``std`` m)."""
    return Band.draw(stream(seed, "compliance"), n_demos, k, std, band)


def velocity_of(path: Callable[[np.ndarray], np.ndarray], t: np.ndarray) -> np.ndarray:
    """ẋ (N, q) of a path given as a function of the stamps t (N,) (its other arguments bound):
    the central difference over ±STEP_S (error ~STEP_S² × the third derivative)."""
    return (path(t + STEP_S) - path(t - STEP_S)) / (2 * STEP_S)


def filtered_velocity(t: np.ndarray, X: np.ndarray, demo: np.ndarray, cutoff: float) -> np.ndarray:
    """What a device that filters its own velocity estimate records: a first-order low-pass at
    ``cutoff`` Hz of the backward difference of the positions X (N, d) on stamps t (N,), started
    at rest in each demonstration: u_n = α u_{n−1} + (1 − α)(x_n − x_{n−1})/Δt, α = e^{−2π f Δt}."""
    from scipy.signal import lfilter

    U = np.zeros_like(X)
    starts = np.flatnonzero(np.r_[True, demo[1:] != demo[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(t)], strict=True):  # a filter per demonstration
        if b - a < 2:
            continue
        dt = np.diff(t[a:b])
        diff = np.vstack([np.zeros((1, X.shape[1])), np.diff(X[a:b], axis=0) / dt[:, None]])
        alpha = float(np.exp(-2 * np.pi * cutoff * np.median(dt)))
        U[a:b] = lfilter([1 - alpha], [1, -alpha], diff, axis=0)
    return U


def observe(seed: int, t: np.ndarray, demo: np.ndarray, x_true: np.ndarray, *, rate: float, noise: float,
            drift: float, velocities: str, filter_hz: float
            ) -> tuple[np.ndarray, np.ndarray, Derivative, dict[str, Any]]:
    """What the sensor records of the true path x_true (N, q): positions X = x_true + drift ·
    t · (a seeded unit direction per demonstration) + white noise of std ``noise``; actions U
    derived by the readers or recorded filtered (module docstring). Returns X, U, how U was made
    and its metadata record."""
    q = x_true.shape[1]
    X = x_true.copy()
    if drift:
        way = unit_rows(stream(seed, "drift").normal(size=(int(demo.max()) + 1, q)))
        X += drift * t[:, None] * way[demo]
    if noise:
        X += stream(seed, "noise").normal(scale=noise, size=X.shape)
    if velocities == "derived":
        U, how = derive(t, X, demo, rate)
        return X, U, Derivative.of(how), how
    U = filtered_velocity(t, X, demo, filter_hz)
    return X, U, Derivative(False), {"recorded": "first-order low-pass of the backward difference",
                                      "filter_hz": filter_hz}


def constrained_truth(xdot: np.ndarray, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Ground truth of the true velocity ẋ (N, q) under orthonormal rows (N, k, q) (module
    docstring): A (N, k, q), N, b, v, w, π."""
    b = np.einsum("nkq,nq->nk", rows, xdot)
    v = np.einsum("nkq,nk->nq", rows, b)
    N = np.eye(xdot.shape[1]) - np.einsum("nki,nkj->nij", rows, rows)
    return {"A": rows, "N": N, "b": b, "v": v, "w": xdot - v, "pi": xdot - v}


def recording(X: np.ndarray, U: np.ndarray, demo: np.ndarray, t: np.ndarray, truth: dict[str, np.ndarray],
              derivative: Derivative, metadata: dict[str, Any]) -> Demonstrations:
    """Demonstrations of positions X (N, q) in m (axes x, y[, z]) and their velocities U (N, q)."""
    axes = ["x", "y", "z"][: X.shape[1]]
    return Demonstrations(X=X, U=U, demo=demo, t=t, truth=truth, state_names=axes,
                          action_names=[f"d{a}/dt" for a in axes], state_units=["m"] * len(axes),
                          action_units=["m/s"] * len(axes), metadata=metadata, derivative=derivative)


def effects_record(*, noise: float, compliance: float, band: tuple[float, float], tremor: float,
                   drift: float, velocities: str, filter_hz: float, how: dict[str, Any]) -> dict[str, Any]:
    """The effects of a simulation, for its ``metadata["effects"]``."""
    return {"noise_m": noise, "compliance_m": compliance, "compliance_hz": list(band), "tremor_m": tremor,
            "tremor_hz": list(TREMOR_HZ), "drift_m_s": drift, "velocities": velocities,
            **({"filter_hz": filter_hz} if velocities == "filtered" else {}), "derivative": how}
