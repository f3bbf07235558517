"""How sure learn-a's ``auto`` is of its answer (issue 30 item 7): each learnt row's cone — its
spread over held-out demonstrations or blocks — and the evidence for one constraint fewer and one
more, stored in ``selection_["sure"]`` (JSON).

*Cone of a row.* The model that won is fitted again without each fold (held-out demonstrations,
or blocks held out inside each demonstration for a model per stretch; for the velocity candidates
these are the held-out rows their rank was read from) and its rows are read at the samples it did
not see: H(x_n) (N, k, q). Row j of the final model, a_j(x_n), lies at

    θ_nj = atan2(‖a_j − P_H a_j‖, ‖P_H a_j‖)        (P_H: projection onto the span of H(x_n))

from them; its cone is the median and 90th percentile of θ_nj over the samples, next to those of
the largest principal angle between the two row spaces. Samples where either has no rows (a
constraint in stretches, where it does not hold) are left out.

*Neighbours.* From the selection table: what speaks against k − 1 (row k holds as well: its
held-out drift or shape residual within its limit, or its held-out motion at the noise level) and
against k + 1 (the best model with one row more misses its limit, or row k + 1 moves beyond the
noise and carries more than a negligible share of the motion).

Shapes: rows (N, k, q); X (N, p), U (N, q), groups (N,), t (N,) s.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ccl_cli.learn.constraint import noise_rank as nr

#: A row counts at a sample when its norm is above this (rows of zeros: the constraint does not hold).
TINY = 1e-12


def _orthonormal(rows: np.ndarray) -> np.ndarray:
    """An orthonormal basis of each sample's rows (N, k, q) → (N, k, q) (batched SVD)."""
    return np.linalg.svd(rows, full_matrices=False)[2]


def angles(final: np.ndarray, held: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sample where both have k rows of non-zero norm: the angle (degrees) of each final row
    from the span of the held-out rows (n, k), the largest principal angle between the two row
    spaces (n,), and which samples count (N,) bool."""
    final, held = np.asarray(final, dtype=float), np.asarray(held, dtype=float)
    k = final.shape[1]
    ok = (np.linalg.norm(final, axis=2) > TINY).all(1) & (np.linalg.norm(held, axis=2) > TINY).all(1)
    if k == 0 or not ok.any():
        return np.zeros((0, k)), np.zeros(0), ok
    F = final[ok] / np.linalg.norm(final[ok], axis=2, keepdims=True)
    Q = _orthonormal(held[ok])
    proj = np.einsum("nkq,njq->nkj", F, Q)  # coefficients of each final row on the held-out basis
    inside = np.linalg.norm(proj, axis=2)
    outside = np.linalg.norm(F - np.einsum("nkj,njq->nkq", proj, Q), axis=2)
    per_row = np.degrees(np.arctan2(outside, inside))
    QF = _orthonormal(F)
    rest = QF - np.einsum("nkj,njq->nkq", np.einsum("nkq,njq->nkj", QF, Q), Q)
    sin = np.linalg.svd(rest, compute_uv=False).max(axis=1)
    return per_row, np.degrees(np.arcsin(np.clip(sin, 0.0, 1.0))), ok


def cone(final: np.ndarray, held: np.ndarray, over: str) -> dict[str, Any] | None:
    """The cone of each learnt row (module docstring) from the final rows and the held-out rows at
    every sample (N, k, q) each; ``over``: how the folds were made. None when no sample has rows."""
    per_row, largest, ok = angles(final, held)
    if not len(largest):
        return None
    rows = [{"row": j + 1, "median_deg": float(np.median(per_row[:, j])),
             "p90_deg": float(np.percentile(per_row[:, j], 90))} for j in range(per_row.shape[1])]
    return {"over": over, "samples": int(ok.sum()), "rows": rows,
            "median_deg": float(np.median(largest)), "p90_deg": float(np.percentile(largest, 90))}


def part(data: nr.Sample, idx: np.ndarray) -> nr.Sample:
    """The samples ``idx`` of a fit's data, with how their actions were made."""
    return nr.Sample(data.X[idx], data.U[idx], data.groups[idx], None if data.t is None else data.t[idx],
                     data.derived, data.recorded)


def held_out_rows(fit: Callable[[np.ndarray], Any], X: np.ndarray, groups: np.ndarray,
                  t: np.ndarray | None, k: int, pairs: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The first k rows of the model ``fit(train)`` returns — fitted on the samples ``train`` —
    at each fold's held-out samples: (N, k, q) (zeros at samples no fold holds out)."""
    rows: np.ndarray | None = None
    for train, test in pairs:
        model = fit(train)
        got = model.constraint(X[test], groups=groups[test], t=None if t is None else t[test])[:, :k]
        if rows is None:
            rows = np.zeros((len(X), k, got.shape[2]))
        rows[test] = got
    return np.zeros((len(X), k, 0)) if rows is None else rows


# -- the evidence for k − 1 and k + 1 ------------------------------------------------------------
def neighbours(selection: dict[str, Any], q: int) -> list[dict[str, Any]]:
    """What the selection table of ``auto`` says about k − 1, k and k + 1 constraints: one entry
    each ({k, role: fewer | chosen | more, rejected, measure, value, limit, words}) for the ranks
    0 … q − 1 around the chosen k."""
    k = int(selection.get("n_constraints") or 0)
    if selection.get("decided_by") == "states":
        found = _by_states((selection.get("geometry") or {}).get("models") or [], k)
    else:
        found = _by_velocities(selection.get("candidates") or [], k)
    return [e for e in found if 0 <= e["k"] <= q - 1]


def _entry(k: int, role: str, rejected: bool | None, measure: str, value: float | None,
           limit: float | None, words: str) -> dict[str, Any]:
    return {"k": k, "role": role, "rejected": rejected, "measure": measure,
            "value": None if value is None else float(value),
            "limit": None if limit is None else float(limit), "words": words}


def judged(measure: str) -> str:
    """How a measure of the states' geometry was judged, in words (after its value)."""
    return (" (each demonstration's own line or circle, the demonstrations agreeing)"
            if measure == "shape residual" else "")


def _model(r: dict[str, Any]) -> str:
    return f"{r['basis']} ({r['scope'].replace('_', ' ')})"


def _by_states(models: list[dict[str, Any]], k: int) -> list[dict[str, Any]]:
    """k ± 1 from the states' geometry (:func:`.geometry.decide` tries the ranks from q − 1 down
    and stops at the first that holds)."""
    def best(r: int, holding: bool = False) -> dict[str, Any] | None:
        """Of rank r: the holding model decide() took as the evidence (a surface in phases first,
        else the least drift), or — ``holding`` False — the nearest to its own limit."""
        at = [m for m in models if m["k"] == r and (m["holds"] or not holding)]
        if holding:
            phased = [m for m in at if m["scope"] == "phases"]
            return phased[0] if phased else min(at, key=lambda m: max(m["drift"])) if at else None
        return min(at, key=lambda m: max(m["drift"]) / m["limit"]) if at else None

    out = []
    evidence, chosen = best(k, holding=True), next((m for m in models if m.get("chosen")), None)
    if evidence is not None:
        row_k = float(evidence["drift"][k - 1])
        out.append(_entry(k - 1, "fewer", True, evidence["measure"], row_k, evidence["limit"],
                          f"row {k} of {_model(evidence)} is held as well: {evidence['measure']} "
                          f"{row_k:.3g} ≤ {evidence['limit']:g}"))
        worst = max(evidence["drift"])
        said = "" if chosen is None or chosen is evidence else (
            f"; chosen: {_model(chosen)}, the simplest within 2× of it ({max(chosen['drift']):.3g})")
        out.append(_entry(k, "chosen", False, evidence["measure"], worst, evidence["limit"],
                          f"{_model(evidence)}: {evidence['measure']} {worst:.3g} ≤ {evidence['limit']:g}"
                          f"{judged(evidence['measure'])}{said}"))
    more = best(k + 1)
    if more is not None:
        worst = max(more["drift"])
        within = worst <= more["limit"]
        why = f"; it does not hold: {more['reason']}" if within and not more["holds"] else ""
        out.append(_entry(k + 1, "more", not more["holds"], more["measure"], worst, more["limit"],
                          f"the best model with {k + 1} rows, {_model(more)}: {more['measure']} {worst:.3g} "
                          f"{'≤' if within else '>'} {more['limit']:g}{why}"))
    return out


def _quiet(r: dict[str, Any], j: int) -> tuple[bool | None, float, float | None, str]:
    """Whether row j (0-based) of a candidate's table row is quiet by its limits (None: the noise
    rule could not judge), its noise ratio, the limit it was held to and the words."""
    ratio, share = r["noise_ratio"][j], r["share"][j]
    limit = (r.get("noise_limit") or [None] * (j + 1))[j]
    share_limit = (r.get("share_limit") or [None] * (j + 1))[j]
    if limit is None:
        return None, ratio, None, r.get("rank_reason") or "the noise rule could not judge"
    by_ratio, by_share = ratio <= limit, share_limit is not None and share <= share_limit
    if by_ratio or by_share:
        what = (f"{ratio:.3g}× its noise (≤ {limit:.3g})" if by_ratio else
                f"{100 * share:.2g} % of the motion (≤ {100 * share_limit:.2g} %)")
        return True, ratio, limit, f"row {j + 1} is quiet on held-out data: {what}"
    said = "" if share_limit is None else f" and carries {100 * share:.2g} % of the motion " \
                                          f"(> {100 * share_limit:.2g} %)"
    return False, ratio, limit, f"row {j + 1} moves {ratio:.3g}× its noise (> {limit:.3g}){said}"


def _by_velocities(candidates: list[dict[str, Any]], k: int) -> list[dict[str, Any]]:
    """k ± 1 from the velocity candidates' held-out rows and the noise rule."""
    tried = [r for r in candidates if r.get("noise_ratio")]
    winner = next((r for r in tried if r.get("chosen")), None)
    measure = "held-out motion / noise"
    out = []
    if winner is not None and k >= 1 and len(winner["noise_ratio"]) >= k:
        quiet, ratio, limit, words = _quiet(winner, k - 1)
        out.append(_entry(k - 1, "fewer", quiet, measure, ratio, limit, f"{winner['class']}: {words}"))
        reached = [r["class"] for r in tried if r.get("k") == k]
        out.append(_entry(k, "chosen", False, measure, ratio, limit,
                          f"{winner['class']} ({k} row(s) quiet on held-out data; of that rank: "
                          f"{', '.join(reached)})"))
    longer = [r for r in tried if len(r["noise_ratio"]) > k and r["class"] != "stretches"]
    if winner is not None and len(winner["noise_ratio"]) > k:
        next_one = winner
    else:  # the candidate closest to a (k + 1)-th row
        next_one = min(longer, key=lambda r: r["noise_ratio"][k], default=None)
    if next_one is not None:
        quiet, ratio, limit, words = _quiet(next_one, k)
        words = f"{next_one['class']}: {words}"
        stretches = next((r for r in tried if r["class"] == "stretches" and r is not next_one), None)
        if next_one["class"] == "stretches" or (stretches is not None and k == 0):
            s = next_one if next_one["class"] == "stretches" else stretches
            words += (f"; in stretches: held in {100 * s['time_share']:.0f} % of the held-out moving time "
                      f"(≥ {100 * s['min_time_share']:.0f} % needed)")
        rejected = None if quiet is None else not quiet or (next_one.get("k") or 0) < k + 1
        out.append(_entry(k + 1, "more", rejected, measure, ratio, limit, words))
    return out


def summary(final: np.ndarray | None, held: np.ndarray | None, over: str, selection: dict[str, Any],
            q: int, why: str = "") -> dict[str, Any]:
    """``selection_["sure"]``: {cone (None with ``why``), neighbours}."""
    found = None if final is None or held is None else cone(final, held, over)
    return {"cone": found, "why": "" if found is not None else why or "no learnt rows",
            "neighbours": neighbours(selection, q)}
