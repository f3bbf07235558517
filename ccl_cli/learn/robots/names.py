"""Matching a log's joint names (e.g. ``sensor_msgs/JointState.name``) to a chain's joints."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ccl_cli.errors import InputError


def _by_prefix(log: list[str], chain: list[str]) -> dict[str, str] | None:
    """chain name → log name through one prefix on one side (P + c in the log for every chain
    name c, or c = P + l for every c); None unless exactly one such mapping exists."""
    first, found = chain[0], []
    for P in {name[: len(name) - len(first)] for name in log if name.endswith(first)} - {""}:
        if all(P + c in log for c in chain):
            found.append({c: P + c for c in chain})
    for P in {first[: len(first) - len(name)] for name in log if name and first.endswith(name)} - {""}:
        if all(c.startswith(P) and c[len(P):] in log for c in chain):
            found.append({c: c[len(P):] for c in chain})
    return found[0] if len(found) == 1 else None


def match_joints(log_names: Sequence[str], chain_names: Sequence[str], *, allow_extra: bool = False,
                 what: str = "the robot") -> np.ndarray:
    """Columns of the log for the chain's joints: ``Q_chain = Q_log[:, index]`` (n,) int.

    Names match exactly, or after one common prefix on either side (``panda_joint1`` ↔
    ``joint1``, ``/arm/a1`` ↔ ``a1``); the order may differ. Joints of the chain missing from
    the log are an :class:`InputError` naming them, and so are log joints not in the chain
    unless ``allow_extra`` (e.g. gripper fingers in the same JointState).
    """
    log = [str(s) for s in log_names]
    chain = [str(s) for s in chain_names]
    for names, side in ((log, "the log"), (chain, what)):
        dup = sorted({s for s in names if names.count(s) > 1})
        if dup:
            raise InputError(f"joint names repeated in {side}: {', '.join(dup)}")
    mapped = {s: s for s in chain}  # chain name → log name
    if chain and not all(s in log for s in chain):
        mapped = _by_prefix(log, chain) or mapped
    missing = [s for s in chain if mapped[s] not in log]
    extra = [s for s in log if s not in mapped.values()]
    if missing or (extra and not allow_extra):
        parts = []
        if missing:
            parts.append(f"joints of {what} missing from the log: {', '.join(missing)}")
        if extra and not allow_extra:
            parts.append(f"log joints not in {what}: {', '.join(extra)}")
        raise InputError("joint names do not match: " + "; ".join(parts)
                         + f" (log: {', '.join(log) or 'none'}; {what}: {', '.join(chain)})")
    return np.array([log.index(mapped[s]) for s in chain], dtype=int)
