"""The :class:`Demonstrations` type: what every reader returns and every learner takes.

Arrays are one sample per row: ``X`` is (N, p), ``U`` is (N, q). Each sample carries
the id of the demonstration (trajectory) it belongs to and a timestamp in seconds.
Ground truth, when known (simulation), lives in ``truth``; learners never read it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, TypeVar

import numpy as np

from ccl_cli.errors import InputError

#: Ground-truth keys and their per-sample shapes (s = number of constraints).
TRUTH_KEYS = ("pi", "w", "v", "b", "A", "N")
#: The readers' local polynomial where a source does not say (the filter assumed when it is not
#: known how the actions were made): its window (samples) and order.
DEFAULT_WINDOW = 9
DEFAULT_ORDER = 2
#: the largest state or action magnitude a run learns from: its square (1e300) still fits float64
MAX_MAGNITUDE = 1e150

T = TypeVar("T")


def first_appearance(ids: np.ndarray) -> np.ndarray:
    """The distinct values of ``ids`` (N,) in order of first appearance: from the starts of
    its runs (O(N)) when no value has two runs (contiguous groups), else by a sort."""
    ids = np.asarray(ids)
    runs = ids[np.r_[0, np.flatnonzero(ids[1:] != ids[:-1]) + 1]] if len(ids) else ids
    if len(np.unique(runs)) == len(runs):
        return runs
    _, first = np.unique(ids, return_index=True)
    return ids[np.sort(first)]


def stamps_assumed(time_used: object) -> bool:
    """Whether a reader's record of the time it used (``metadata`` "time" or "time_column": a
    column, a dataset, or "rate R Hz") says the stamps were made from an assumed rate."""
    return str(time_used or "").startswith("rate")


def group_rows(groups: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The distinct ids of ``groups`` (N,) in ascending order (as ``np.unique``) and, for each,
    its row indices in ascending order (as ``np.flatnonzero(groups == id)``): one stable sort,
    O(N log N) — not one pass over the N rows per id, which is quadratic in the number of
    demonstrations."""
    groups = np.asarray(groups)
    if len(groups) == 0:
        return groups[:0], []
    if np.all(groups[1:] >= groups[:-1]):  # ids in order already (the usual layout): no sort
        order = np.arange(len(groups))
        ordered = groups
    else:
        order = np.argsort(groups, kind="stable")
        ordered = groups[order]
    cuts = np.flatnonzero(ordered[1:] != ordered[:-1]) + 1
    return ordered[np.r_[0, cuts]], np.split(order, cuts)


@dataclass(frozen=True)
class Derivative:
    """How the actions U were made from the states X — a fact of the data, set by the reader
    or simulator that made them.

    Attributes:
        derived: True when U = dX/dt by the readers' local polynomial
            (:mod:`ccl_cli.io.derivative`), False when the actions were recorded (or are a
            model's output), None when nothing says.
        window, order: the polynomial's samples and degree (:data:`DEFAULT_WINDOW`,
            :data:`DEFAULT_ORDER` where the source does not say).
        rule: why that window, in words ("" when not said).
    """

    derived: bool | None = None
    window: int = DEFAULT_WINDOW
    order: int = DEFAULT_ORDER
    rule: str = ""

    @classmethod
    def of(cls, value: HowMade) -> Derivative:
        """The value a learner's ``derivative`` argument takes: a Derivative; the readers'
        ``{"window", "order"}`` (derived); False (recorded); None (not known)."""
        if isinstance(value, Derivative):
            return value
        if isinstance(value, Mapping):
            return cls(True, int(value.get("window") or DEFAULT_WINDOW),
                       int(value.get("order") or DEFAULT_ORDER), str(value.get("window_rule") or ""))
        if value is None or value is False:
            return cls(None if value is None else False)
        raise InputError(f"derivative must say how the actions were made (a Derivative, "
                         f"{{window, order}}, False or None), got {value!r}"[:200])

    @classmethod
    def from_record(cls, record: Any) -> Derivative | None:
        """From a record a source stored (a reader's ``{"derived", "window", "order", ...}``, a
        simulator's ``{"window", "order"}``, a recorded stream's description): derived when it
        names a window or says derived, else recorded; None when ``record`` is no mapping."""
        if not isinstance(record, Mapping):
            return None
        if "derived" in record or "window" in record:
            return cls.of(record)
        return cls(False)

    @property
    def known(self) -> bool:
        return self.derived is not None

    def gain(self, dt: float) -> float:
        """Σc² of the polynomial's slope filter c (1/s) on stamps ``dt`` s apart: the variance
        of a derived velocity per unit variance of white position noise."""
        from ccl_cli.learn.noise import slope_filter

        return float((slope_filter(dt, self.window, self.order) ** 2).sum())

    def as_dict(self) -> dict[str, Any]:
        return {"derived": self.derived, "window": self.window, "order": self.order, "rule": self.rule}


#: What a learner's ``derivative`` argument takes (:meth:`Derivative.of`).
HowMade = Derivative | Mapping[str, Any] | bool | None


@dataclass(frozen=True, eq=False)
class Repair:
    """What sensor-fault repair (:mod:`ccl_cli.io.faults`) did to each sample it saw — the
    samples of the recording(s) as read, in order, before any was dropped — and why.

    Attributes:
        done: (M,) index into :data:`ACTIONS` — ``kept`` (as recorded), ``mirrored`` (a
            hemisphere flip mirrored back), ``restamped`` (its stamp repaired) or ``dropped``.
        why: (M,) index into ``faults``: the kind of fault behind it (``faults[0]`` is "":
            none found; a kept sample with a fault was found faulty and kept as recorded).
        faults: the kinds of fault named in ``why``.
        row: (M,) the row of X/U the sample is, −1 when it is not in the data (dropped by the
            repair, or left out afterwards: outside every demonstration, a held-out part, ...).
    """

    ACTIONS: ClassVar[tuple[str, ...]] = ("kept", "mirrored", "restamped", "dropped")

    done: np.ndarray
    why: np.ndarray
    faults: tuple[str, ...]
    row: np.ndarray

    @classmethod
    def untouched(cls, n: int) -> Repair:
        """n samples checked and kept as recorded, row i the i-th."""
        return cls(np.zeros(n, np.uint8), np.zeros(n, np.uint8), ("",), np.arange(n, dtype=np.int64))

    def actions(self) -> np.ndarray:
        """(M,) what was done to each sample, in words."""
        return np.asarray(self.ACTIONS)[self.done]

    def reasons(self) -> np.ndarray:
        """(M,) the fault behind it ("" where none was found)."""
        return np.asarray(self.faults)[self.why]

    def of_rows(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(what was done, why) for each of the ``n`` rows of the data, in words: (n,) each
        (a row no repaired sample became — data that were not checked — is ``kept``, "")."""
        done, why = np.full(n, "kept", dtype=object), np.full(n, "", dtype=object)
        on = self.row >= 0
        done[self.row[on]], why[self.row[on]] = self.actions()[on], self.reasons()[on]
        return done, why

    def places(self, demo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where each sample seen lies among the data's rows, whose demonstration ids are ``demo``
        (n,): rows ``a``, ``b`` (M,) and weight ``w`` (M,) such that the sample is at
        (1 − w)·row a + w·row b. A sample in the data: its row twice, w 0. A sample the repair
        dropped: between the nearest samples it did not drop before and after it (w by position),
        when both are rows of one demonstration; else at the nearer one (the earlier on a tie),
        when that is a row. −1 where the sample has no place in the data: left out afterwards
        (outside every demonstration, ...), or dropped nearer to such a sample than to a row."""
        m = len(self.row)
        i = np.arange(m)
        inside = self.row >= 0
        stays = self.done != self.ACTIONS.index("dropped")
        before = np.maximum.accumulate(np.where(stays, i, -1))
        after = np.minimum.accumulate(np.where(stays, i, m)[::-1])[::-1]
        row = np.r_[self.row, -1]  # index −1 and m: no such sample
        ra, rb = row[before], row[np.minimum(after, m)]
        ids = np.r_[np.asarray(demo), -1]
        between = (ra >= 0) & (rb >= 0) & (ids[ra] == ids[rb]) & (after > before)
        nearer = np.where((before >= 0) & ((i - before <= after - i) | (after >= m)), ra, rb)
        a = np.where(inside, self.row, np.where(between, ra, nearer))
        b = np.where(inside, self.row, np.where(between, rb, nearer))
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(inside | ~between, 0.0, (i - before) / np.maximum(after - before, 1))
        return a, b, w

    def after(self, kept: np.ndarray, n: int) -> Repair:
        """The record once the data's ``n`` rows are cut to ``kept`` (a mask (n,) or row indices,
        in the new order): each sample's row where it went, −1 where it left."""
        new_of_old = np.full(n + 1, -1, dtype=np.int64)  # entry n: the −1 of samples already out
        idx = np.flatnonzero(kept) if np.asarray(kept).dtype == bool else np.asarray(kept, dtype=np.int64)
        new_of_old[idx] = np.arange(len(idx))
        return replace(self, row=new_of_old[np.where(self.row >= 0, self.row, n)])

    @staticmethod
    def join(parts: list[tuple[Repair | None, int]]) -> Repair | None:
        """One record of datasets joined in order: (record or None — not checked: its rows kept —
        and its row count) each; None when no part holds one."""
        if all(r is None for r, _ in parts):
            return None
        faults = tuple(dict.fromkeys(k for r, _ in parts if r is not None for k in r.faults))
        if "" not in faults:
            faults = ("", *faults)
        done, why, row, offset = [], [], [], 0
        for r, n in parts:
            r = r if r is not None else Repair.untouched(n)
            code = np.array([faults.index(k) for k in r.faults], dtype=np.uint8)
            done.append(r.done)
            why.append(code[r.why])
            row.append(np.where(r.row >= 0, r.row + offset, -1))
            offset += n
        return Repair(np.concatenate(done), np.concatenate(why), faults, np.concatenate(row))

    def counts(self) -> dict[str, dict[str, int]]:
        """action → fault → number of samples (faults "" : none found)."""
        out: dict[str, dict[str, int]] = {}
        pairs, n = np.unique(np.stack([self.done, self.why], 1), axis=0, return_counts=True)
        for (a, w), k in zip(pairs, n, strict=True):
            out.setdefault(self.ACTIONS[a], {})[self.faults[w]] = int(k)
        return out


@dataclass
class Demonstrations:
    """Observed states and actions grouped into demonstrations.

    Attributes:
        X: states, (N, p).
        U: actions, (N, q).
        demo: demonstration id of each sample, (N,) int; samples of one
            demonstration are contiguous and in time order.
        t: time of each sample in seconds, (N,).
        truth: optional ground truth: ``pi``, ``w``, ``v`` (N, q); ``b`` (N, s);
            ``A`` (s, q) constant or (N, s, q); ``N`` (q, q) constant or (N, q, q).
        state_names, action_names: length p and q.
        state_units, action_units: length p and q (free text, may be empty).
        metadata: JSON-serialisable provenance (source files, topics, ...).
        derivative: how U was made (:class:`Derivative`; not known by default).
        repair: what sensor-fault repair did to each sample it saw (:class:`Repair`; None
            when no check ran).
        force: the force a force/torque sensor measured at each sample, in the base frame (the
            frame of the states' positions), (N, 3) finite; None when the log has none.
    """

    X: np.ndarray
    U: np.ndarray
    demo: np.ndarray | None = None
    t: np.ndarray | None = None
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    state_names: list[str] | None = None
    action_names: list[str] | None = None
    state_units: list[str] | None = None
    action_units: list[str] | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    derivative: Derivative = field(default_factory=Derivative)
    repair: Repair | None = None
    force: np.ndarray | None = None
    #: figures of these arrays computed once (:meth:`memo`): name → (the fields they were
    #: computed from, the value)
    _memo: dict[str, tuple[tuple, Any]] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.X = np.asarray(self.X, dtype=float)
        self.U = np.asarray(self.U, dtype=float)
        if self.X.ndim == 1:
            self.X = self.X[:, None]
        if self.U.ndim == 1:
            self.U = self.U[:, None]
        if self.X.ndim != 2 or self.U.ndim != 2:
            raise InputError(f"X and U must be 2-D (N×p, N×q), got {self.X.shape} and {self.U.shape}")
        n = self.X.shape[0]
        if self.U.shape[0] != n:
            raise InputError(f"X has {n} samples but U has {self.U.shape[0]}")
        self.demo = np.zeros(n, dtype=np.int64) if self.demo is None else \
            np.asarray(self.demo, dtype=np.int64)  # no copy of int64 ids
        self.t = np.arange(n, dtype=float) if self.t is None else np.asarray(self.t, dtype=float)
        if self.demo.shape != (n,) or self.t.shape != (n,):
            raise InputError(f"demo and t must have shape ({n},)")
        p, q = self.X.shape[1], self.U.shape[1]
        self.state_names = list(self.state_names or [f"x{i}" for i in range(p)])
        self.action_names = list(self.action_names or [f"u{i}" for i in range(q)])
        self.state_units = list(self.state_units or [""] * p)
        self.action_units = list(self.action_units or [""] * q)
        if len(self.state_names) != p or len(self.action_names) != q:
            raise InputError("state_names/action_names do not match the dimensions of X/U")
        for key in self.truth:
            if key not in TRUTH_KEYS:
                raise InputError(f"unknown ground-truth key {key!r} (known: {', '.join(TRUTH_KEYS)})")
        self.truth = {k: np.asarray(v, dtype=float) for k, v in self.truth.items()}
        if self.force is not None:
            self.force = np.asarray(self.force, dtype=float)
            if self.force.shape != (n, 3):
                raise InputError(f"force must hold one 3-D force per sample, ({n}, 3), got "
                                 f"{self.force.shape}")
            if not np.isfinite(self.force).all():
                row = int(np.argwhere(~np.isfinite(self.force))[0][0])
                raise InputError(f"force has non-finite values (first at row {row})")

    # -- sizes ------------------------------------------------------------------------
    @property
    def n_samples(self) -> int:
        return int(self.X.shape[0])

    @property
    def n_state(self) -> int:
        return int(self.X.shape[1])

    @property
    def n_action(self) -> int:
        return int(self.U.shape[1])

    def memo(self, name: str, compute: Callable[[], T]) -> T:
        """``compute()``, a read-only figure of this data, computed once: kept under ``name``
        while X, U, demo, t, the derivative and the repair record are the objects it was
        computed from (a field set anew computes it again). The caller must not modify it."""
        key = (self.X, self.U, self.demo, self.t, self.derivative, self.repair)
        kept = self._memo.get(name)
        if kept is not None and all(a is b for a, b in zip(kept[0], key, strict=True)):
            return kept[1]
        value = compute()
        self._memo[name] = (key, value)
        return value

    @property
    def rate_assumed(self) -> bool:
        """Whether the sample times were made from an assumed rate (``data.time.rate``, no stamps
        in any file): a length in seconds is then a number of samples at a rate nobody measured."""
        files = self.metadata.get("files") or []

        def paced(entry: Mapping[str, Any]) -> bool:
            state = entry.get("state")
            return stamps_assumed(entry.get("time")) or \
                (isinstance(state, Mapping) and stamps_assumed(state.get("time_column")))

        return bool(files) and all(isinstance(f, Mapping) and paced(f) for f in files)

    @property
    def demo_ids(self) -> np.ndarray:
        """Distinct demonstration ids in order of first appearance (computed once)."""
        return self.memo("demo_ids", lambda: first_appearance(self.demo))

    @property
    def n_demos(self) -> int:
        return int(len(self.demo_ids))

    def __len__(self) -> int:
        return self.n_samples

    # -- ground truth -----------------------------------------------------------------
    def has_truth(self, *keys: str) -> bool:
        return all(k in self.truth for k in keys)

    def truth_per_sample(self, key: str) -> np.ndarray:
        """Ground truth ``key`` broadcast to one entry per sample.

        ``A`` becomes (N, s, q) and ``N`` (N, q, q) when stored as constants.
        """
        value = self.truth[key]
        if key in ("A", "N") and value.ndim == 2:
            return np.broadcast_to(value, (self.n_samples, *value.shape))
        return value

    def true_projection(self, per_sample: bool = True) -> np.ndarray:
        """True null-space projection N_n (N, q, q), from ``N`` or from ``A``; with
        ``per_sample=False`` one (q, q) when the truth is constant (N × q² floats fewer)."""
        key = "N" if "N" in self.truth else "A"
        if key in self.truth and not per_sample and self.truth[key].ndim == 2:
            if key == "N":
                return self.truth["N"]
            from ccl_cli.learn.linalg import nullspace_projection

            return nullspace_projection(self.truth["A"][None])[0]
        if "N" in self.truth:
            return np.asarray(self.truth_per_sample("N"))
        if "A" in self.truth:
            from ccl_cli.learn.linalg import nullspace_projection

            return nullspace_projection(np.asarray(self.truth_per_sample("A")))
        raise InputError("no ground-truth constraint (A or N) in this dataset")

    # -- selection --------------------------------------------------------------------
    def without_truth(self) -> Demonstrations:
        """The same samples (the same arrays, and what :meth:`memo` kept of them) without the
        ground truth."""
        out = replace(self, truth={})
        out._memo.update(self._memo)
        return out

    def subset(self, mask: np.ndarray) -> Demonstrations:
        """The samples where ``mask`` (bool (N,) or index array) holds."""
        idx = np.asarray(mask)
        n = self.n_samples
        truth = {}
        for key, value in self.truth.items():
            if value.ndim >= 1 and value.shape[0] == n and not (key in ("A", "N") and value.ndim == 2):
                truth[key] = value[idx]
            else:
                truth[key] = value
        repair = None if self.repair is None else self.repair.after(idx, n)
        return replace(self, X=self.X[idx], U=self.U[idx], demo=self.demo[idx], t=self.t[idx],
                       truth=truth, metadata=dict(self.metadata), repair=repair,
                       force=None if self.force is None else self.force[idx])

    def select_demos(self, ids: np.ndarray | list[int]) -> Demonstrations:
        return self.subset(np.isin(self.demo, np.asarray(ids)))

    def split(self, fraction: float = 0.3, seed: int = 0) -> tuple[Demonstrations, Demonstrations]:
        """Seeded train/test split by demonstration; ``fraction`` of demos go to test.

        With a single demonstration the split is by time: the last ``fraction`` of it.
        """
        if not 0.0 < fraction < 1.0:
            raise InputError(f"test fraction must be in (0, 1), got {fraction}")
        ids = self.demo_ids
        if len(ids) < 2:
            cut = int(round(self.n_samples * (1.0 - fraction)))
            train = np.arange(self.n_samples) < cut
            return self.subset(train), self.subset(~train)
        rng = np.random.default_rng(seed)
        n_test = min(max(1, int(round(fraction * len(ids)))), len(ids) - 1)
        test_ids = rng.choice(ids, size=n_test, replace=False)
        test = np.isin(self.demo, test_ids)
        return self.subset(~test), self.subset(test)

    @staticmethod
    def concatenate(parts: list[Demonstrations]) -> Demonstrations:
        """Join datasets, renumbering demonstrations so ids stay distinct."""
        if not parts:
            raise InputError("no demonstrations to concatenate")
        first = parts[0]
        offset = 0
        demos = []
        for part in parts:
            if part.n_state != first.n_state or part.n_action != first.n_action:
                def named(d: Demonstrations) -> str:
                    source = d.metadata.get("source") or "a dataset"
                    return f"{source} (state p = {d.n_state}, action q = {d.n_action})"

                raise InputError(f"cannot join {named(part)} with {named(first)}: every file must give the "
                                 "same state and action dimensions (select the same joints or columns, "
                                 "e.g. data.state.joints, or run the files separately)")
            _, inv = np.unique(part.demo, return_inverse=True)
            demos.append(inv + offset)
            offset += int(inv.max()) + 1 if len(inv) else 0
        forces = [p.force is not None for p in parts]
        if any(forces) and not all(forces):
            part = parts[forces.index(False)]
            raise InputError(f"{part.metadata.get('source') or 'a dataset'} has no force channel while "
                             "others have one: give every file the same data.force mapping")
        keys = set.intersection(*(set(p.truth) for p in parts))
        truth = {}
        for key in keys:
            vals = [p.truth_per_sample(key) for p in parts]
            truth[key] = np.concatenate([np.asarray(v) for v in vals])
        return Demonstrations(
            X=np.concatenate([p.X for p in parts]),
            U=np.concatenate([p.U for p in parts]),
            demo=np.concatenate(demos),
            t=np.concatenate([p.t for p in parts]),
            truth=truth,
            state_names=first.state_names,
            action_names=first.action_names,
            state_units=first.state_units,
            action_units=first.action_units,
            metadata={"parts": [p.metadata for p in parts]},
            derivative=next((p.derivative for p in parts if p.derivative.known), Derivative()),
            repair=Repair.join([(p.repair, p.n_samples) for p in parts]),
            force=np.concatenate([p.force for p in parts]) if all(forces) else None,
        )

    def check_finite(self) -> None:
        """Refuse NaN or inf, and values beyond ±:data:`MAX_MAGNITUDE` (no measurement: a
        damaged number, whose square overflows float64 in every least-squares fit)."""
        for name, arr in (("X", self.X), ("U", self.U)):
            bad = ~np.isfinite(arr)
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                count = int(bad.any(axis=1).sum())
                raise InputError(f"{name} has {count} non-finite samples (first at row {row})")
            huge = np.abs(arr) > MAX_MAGNITUDE
            if huge.any():
                row, col = (int(i) for i in np.argwhere(huge)[0])
                column = (self.state_names if name == "X" else self.action_names)[col]
                count = int(huge.any(axis=1).sum())
                raise InputError(f"{name} has {count} samples beyond ±{MAX_MAGNITUDE:g} "
                                 f"(first at row {row}, {column} = {arr[row, col]:.3g}): no measurement is "
                                 "that large; a damaged recording?")
