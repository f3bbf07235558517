"""Forces as evidence in learn-a's ``auto`` (DESIGN.md "Evidence for a constraint"): what the force
channel says beside the states and the velocities.

:func:`weigh` runs after ``auto`` has chosen from the states' geometry or the velocity candidates.
The force shows contact stretches and their rows (:mod:`.contact`: a reaction along the row and no
motion along it) — positive evidence of one constraint where the tool touches, and of free motion
elsewhere:

* no contact anywhere: the answer stands; ``selection_["forces"]`` says the force never reacts;
* the answer holds more rows than one everywhere (a hinge keeps the hand on a circle: two rows,
  of which the handle's pull shows one), or holds one row everywhere while contact covers at least
  ALL_ALONG of the samples: the answer stands, the forces *supporting* it when the contact rows lie
  within SUPPORT_DEG of its rows (else *disagreeing*), said in its reason;
* otherwise (no constraint, or one only in stretches, or a fixed k of one) the forces decide: a
  :class:`~.contact_phases.ContactPhases` — the contact stretches with their rows, free motion
  elsewhere — with ``decided_by`` "forces" and what the states and velocities said instead.

Held-out evidence for a decision by forces: each contact stretch is cut into HELD_BLOCKS contiguous
blocks; the row fitted without a block (the velocities' smallest direction over the rest, as the
stretch's own) is read on it — the cone of each row (:func:`.sure.cone`), the block's motion share
along it, and the held-out NPOE (§6) with Ñ = I − nnᵀ in contact and I elsewhere.

Shapes: X (N, p), U (N, 3), groups (N,), t (N,) s, force (N, 3).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.constraint import contact as ct
from ccl_cli.learn.constraint import sure
from ccl_cli.learn.constraint.contact_phases import fitted_from
from ccl_cli.learn.linalg import nullspace_projection

#: Contact over at least this share of the samples counts as "all along" (a wipe that never lifts).
ALL_ALONG = 0.85
#: Contact rows within this angle (degrees, median over the contact samples) of the answer's rows
#: support it.
SUPPORT_DEG = 15.0
#: Blocks per contact stretch for the held-out check.
HELD_BLOCKS = 5


def weigh(auto: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None, t: np.ndarray | None,
          force: np.ndarray) -> None:
    """Weigh the force (N, 3) against the answer ``auto`` (a fitted AutoConstraint) chose on X (N, p),
    U (N, q) of demonstrations ``groups`` at times ``t`` (module docstring): ``selection_["forces"]``
    always; ``model_``, ``n_constraints_``, ``selection_`` and ``heldout_`` when the forces decide."""
    n, q = U.shape
    force = np.asarray(force, dtype=float)
    if force.shape != (n, 3) or not np.isfinite(force).all():
        raise InputError(f"force must hold one finite 3-D force per sample, ({n}, 3), got {force.shape}"
                         + ("" if force.shape != (n, 3) else " with non-finite values"))
    g = np.zeros(n, np.int64) if groups is None else np.asarray(groups)
    why_not = (f"the actions have {q} dimensions; a force speaks for 3-D task-space motion" if q != 3 else
               "needs the sample times" if t is None else None)
    if why_not is not None:
        auto.selection_["forces"] = {"used": False, "reason": why_not}
        return
    t = np.asarray(t, float)
    found = ct.find(force, U, g, t)
    info: dict[str, Any] = {"used": True, **found.summary(t, g)}
    old, k_old = auto.model_, int(auto.n_constraints_)
    if not found.stretches:
        held = [d for d, v in found.held.items() if v > 0.5]
        info.update(role="no contact", reason="the force never pushes along a direction the motion does not "
                    "take: no contact" + (f" (held channel in demonstration(s) {held})" if held else ""))
        _said(auto, info)
        return
    everywhere = bool(np.asarray(old.holds(X, groups=g, t=t)).all()) if k_old else False
    fixed = auto.n_constraints
    if fixed is not None and fixed != 1:
        info.update(role="not deciding", reason=f"n_constraints is fixed at {fixed}; contact shows one row")
    elif everywhere and (k_old > 1 or found.mask.mean() >= ALL_ALONG):
        angle = _agreement(found, old.constraint(X, groups=g, t=t))
        supports = angle <= SUPPORT_DEG
        info.update(role="supporting" if supports else "disagreeing", angle_deg=angle, reason=(
            f"contact in {100 * found.mask.mean():.0f} % of the samples, its rows {angle:.1f}° from the "
            f"answer's {k_old} row(s) (median; {'≤' if supports else '>'} {SUPPORT_DEG:g}°)"))
    else:
        _decide(auto, found, info, X, U, g, t)
        return
    _said(auto, info)


def _said(auto: Any, info: dict[str, Any]) -> None:
    """The forces' finding recorded beside an answer that stands (and in its reason)."""
    auto.selection_["forces"] = info
    said = f"forces: {info['role']} ({info['reason']})"
    auto.selection_["reason"] = f"{auto.selection_.get('reason', '')}; {said}"
    inner = getattr(auto.model_, "selection_", None)
    if isinstance(inner, dict):
        auto.model_.selection_ = {**inner, "forces": info, "reason": auto.selection_["reason"]}


def _agreement(found: ct.Contact, rows: np.ndarray) -> float:
    """Median over the contact samples of each contact row's angle (degrees) from the span of the
    answer's rows there (N, k, q)."""
    on = found.mask
    per_row, _, ok = sure.angles(found.rows()[on], rows[on])
    return float(np.median(per_row[:, 0])) if ok.any() else 90.0


def _decide(auto: Any, found: ct.Contact, info: dict[str, Any], X: np.ndarray, U: np.ndarray,
            g: np.ndarray, t: np.ndarray) -> None:
    """The forces decide: ``auto`` answers with the contact stretches (module docstring)."""
    before = {"n_constraints": int(auto.n_constraints_), "model": auto.selection_.get("model"),
              "decided_by": auto.selection_.get("decided_by", "velocities"),
              "reason": auto.selection_.get("reason")}
    model = fitted_from(found, X, U, g, t)
    held = held_out(found, U, g, t)
    info.update(role="decided", reason=model.summary(), instead_of=before, heldout=held["support"])
    auto.model_ = model
    auto.n_constraints_ = 1
    auto.heldout_ = held["npoe"]
    model.heldout_ = held["npoe"]
    rows = [{"class": "forces", "model": "contact stretches from the forces", "k": 1, "chosen": True,
             "reason": "a reaction along the row and no motion along it"}]
    rows += [{**r, "chosen": False} for r in auto.selection_.get("candidates") or []]
    selection = {
        "rule": "auto", "n_constraints": 1, "model": "contact stretches from the forces (one row each, free "
        "elsewhere)", "chosen": "contact", "decided_by": "forces",
        "reason": (f"1 constraint in contact, none elsewhere: {model.summary()}; the states and velocities "
                   f"alone said {before['n_constraints']} ({before['model']})"),
        "values": [s.motion_share for s in found.stretches],
        "criterion": "share of each contact stretch's motion along its row",
        "candidates": rows, "forces": info, **({"geometry": auto.selection_["geometry"]}
                                                if "geometry" in auto.selection_ else {})}
    selection["sure"] = {"cone": held["cone"], "why": "" if held["cone"] else "no held-out blocks",
                         "neighbours": _neighbours(found, U, info)}
    auto.selection_ = selection
    model.selection_ = {**selection, "winner_selection": model.selection_}


def held_out(found: ct.Contact, U: np.ndarray, groups: np.ndarray, t: np.ndarray) -> dict[str, Any]:
    """The held-out check of a decision by forces (module docstring): {cone, npoe ({error, mean, se,
    per_fold, folds} or None), support ({supported, why})}."""
    n = len(U)
    final, held = found.rows(), np.zeros((n, 1, 3))
    fold = np.full(n, -1)
    shares = []
    for s in found.stretches:  # a loop over stretches, each over its few blocks
        blocks = np.array_split(np.arange(s.start, s.stop), HELD_BLOCKS)
        for j, test in enumerate(blocks):
            train = np.setdiff1d(np.arange(s.start, s.stop), test)
            e1 = np.linalg.eigh(U[train].T @ U[train])[1][:, 0]
            held[test, 0] = e1
            fold[test] = j
            C = U[test].T @ U[test]
            shares.append(float(e1 @ C @ e1 / max(np.trace(C), np.finfo(float).tiny)))
    on = fold >= 0
    cone = sure.cone(final[on], held[on], f"{HELD_BLOCKS} blocks held out inside each contact stretch")
    N = nullspace_projection(np.where(on[:, None, None], held, 0.0))
    errors = np.array([npoe_error(N[fold == j], U[fold == j]) for j in range(HELD_BLOCKS)
                       if (fold == j).any()])
    npoe = None if not len(errors) else {
        "error": "NPOE", "mean": float(errors.mean()), "se": float(errors.std(ddof=1) / np.sqrt(len(errors)))
        if len(errors) > 1 else 0.0, "per_fold": errors.tolist(),
        "folds": f"{HELD_BLOCKS} blocks held out inside each contact stretch"}
    worst = float(np.median(shares)) if shares else 1.0
    ok = worst <= ct.GROW_SHARE
    support = {"supported": ok, "why": (f"rows fitted without a block carry a median {100 * worst:.2g} % of "
                                        f"its motion ({'≤' if ok else '>'} {100 * ct.GROW_SHARE:.0f} %)")}
    return {"cone": cone, "npoe": npoe, "support": support}


def _neighbours(found: ct.Contact, U: np.ndarray, info: dict[str, Any]) -> list[dict[str, Any]]:
    """k ± 1 of a decision by forces: 0 rows is refuted by the reaction (the stretches' motion share
    along their rows), 2 rows by the motion along the second quietest direction of each stretch."""
    along, second = [], []
    for s in found.stretches:  # a loop over stretches
        lam = np.linalg.eigvalsh(U[s.start:s.stop].T @ U[s.start:s.stop])
        along.append(s.motion_share)
        second.append(float(lam[1] / max(lam.sum(), np.finfo(float).tiny)))
    a, b = float(np.median(along)), float(np.median(second))
    entry = {"measure": "share of the contact stretches' motion", "limit": ct.GROW_SHARE}
    return [
        {**entry, "k": 0, "role": "fewer", "rejected": True, "value": a,
         "words": f"the force pushes along the row while the motion along it is {100 * a:.2g} % of the "
                  "stretch's"},
        {**entry, "k": 1, "role": "chosen", "rejected": False, "value": a, "words": info["reason"]},
        {**entry, "k": 2, "role": "more", "rejected": b > ct.GROW_SHARE, "value": b,
         "words": f"the next quietest direction carries {100 * b:.2g} % of the stretches' motion"}]


def fit_params(model: Any, force: np.ndarray | None) -> dict[str, Any]:
    """``{"force": force}`` for a learner whose ``fit`` takes a force (learn-a's ``auto``, contact
    phases) when there is one, else {}: what the app passes to ``fit`` beside X and U."""
    import inspect

    takes = "force" in inspect.signature(model.fit).parameters
    return {"force": force} if takes and force is not None else {}
