"""A force channel read beside the state (``data.force``, :class:`~ccl_cli.io.options.ForceOptions`).

Every format names the force as it names the state — CSV columns, a topic's field (a
``geometry_msgs/WrenchStamped``: ``field: wrench.force``), an HDF5 dataset, a .mat variable,
with ``columns`` to pick fx, fy, fz out of a wider array — and, for a force measured in the
tool's frame, the tool's orientation as a unit quaternion per sample (``orientation``, scalar
first ``wxyz`` or last ``xyzw``). What the readers hand on is the force in the base frame,
f = R(q) f_tool, one (3,) row per sample of the state (:attr:`~ccl_cli.dataset.Demonstrations.force`).

* Stream formats (CSV, bags, MCAP): the force (and orientation) streams are read in the same pass
  as the state, their non-finite samples dropped (or refused, ``nonfinite``), and interpolated
  linearly onto the state's stamps (quaternions with their signs made continuous first, then
  normalised); the state's samples outside the force's span are dropped, as for a recorded action.
* Array formats (HDF5 layouts, .mat): the force lies beside the state, sample for sample; it goes
  through the same cuts, non-finite drops and fault repairs as the state.

A channel that is not zeroed reads a constant offset where the tool touches nothing: it is
reported (``force_bias``, :func:`ccl_cli.io.faults.force_bias`), never removed — the learner
measures the force against its own quiet level. Shapes: force (N, 3), quaternions (N, 4).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.options import DataOptions, ForceOptions, StreamOptions

#: The array keys of the force and the tool's orientation (array formats).
KEYS = ("force", "orientation")
#: A quaternion whose norm is off 1 by more than this is not a rotation (a wrong column, a
#: position): refused. Within it, quaternions are normalised.
UNIT_TOLERANCE = 0.05


def selections(options: DataOptions) -> dict[str, StreamOptions]:
    """The force stream and, for a tool-frame force, the orientation stream the options name,
    by key (empty without ``data.force``)."""
    force = options.force
    if force is None:
        return {}
    out: dict[str, StreamOptions] = {"force": force}
    if force.orientation is not None:
        out["orientation"] = force.orientation
    return out


def plain(selection: StreamOptions) -> StreamOptions:
    """A force or orientation selection as the readers' plain :class:`StreamOptions`."""
    return StreamOptions(**{k: getattr(selection, k) for k in StreamOptions.model_fields
                            if getattr(selection, k) is not None})


def option_path(key: str) -> str:
    """The config path of a key of :data:`KEYS` (for messages)."""
    return "data.force" if key == "force" else "data.force.orientation"


def check_width(values: np.ndarray, key: str, where: str) -> np.ndarray:
    """``values`` (n, d) checked to be a force (d = 3) or a quaternion (d = 4)."""
    want = 3 if key == "force" else 4
    if values.ndim != 2 or values.shape[1] != want:
        got = values.shape[1] if values.ndim == 2 else values.ndim
        how = ("fx, fy, fz: pick them with columns: [...] or field: wrench.force" if key == "force" else
               "a quaternion: pick its columns with columns: [...]")
        raise InputError(f"{where}: {option_path(key)} needs {want} numbers per sample ({how}), got {got}")
    return values


def rotation(quaternions: np.ndarray, convention: str, where: str) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of quaternions (n, 4) in ``convention`` (wxyz or xyzw),
    normalised; one whose norm is off 1 by more than UNIT_TOLERANCE is refused, naming its row."""
    Q = np.asarray(quaternions, dtype=float)
    if convention == "xyzw":
        Q = Q[:, [3, 0, 1, 2]]
    norm = np.linalg.norm(Q, axis=1)
    bad = ~(np.abs(norm - 1.0) <= UNIT_TOLERANCE)
    if bad.any():
        row = int(np.argmax(bad))
        raise InputError(f"{where}: data.force.orientation is not a unit quaternion at sample {row} (norm "
                         f"{norm[row]:.3g}); check its columns and convention ({convention})")
    w, x, y, z = (Q / norm[:, None]).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], 1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], 1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], 1)], 1)


def convention(force: ForceOptions, where: str) -> str:
    """The quaternion convention: as given, xyzw for a topic (ROS's field order), else refused."""
    orientation = force.orientation
    if orientation.convention is not None:
        return orientation.convention
    if orientation.topic is not None:
        return "xyzw"
    raise InputError(f"{where}: data.force.orientation.convention must say how the quaternion's "
                     "columns are ordered: wxyz (scalar first) or xyzw (scalar last)")


def base_frame(force: np.ndarray, orientation: np.ndarray | None, options: ForceOptions, where: str
               ) -> np.ndarray:
    """The force (n, 3) in the base frame: as read (``frame: base``) or rotated by the tool's
    orientation (n, 4), f = R(q) f_tool."""
    force = check_width(np.asarray(force, dtype=float), "force", where)
    if options.frame == "base":
        return force
    orientation = check_width(np.asarray(orientation, dtype=float), "orientation", where)
    R = rotation(orientation, convention(options, where), where)
    return np.einsum("nij,nj->ni", R, force)


def continuous(quaternions: np.ndarray) -> np.ndarray:
    """Quaternions (n, 4) with signs flipped so that neighbours agree (q and −q are one rotation):
    what linear interpolation between them needs."""
    Q = np.asarray(quaternions, dtype=float)
    flip = np.r_[False, (Q[1:] * Q[:-1]).sum(1) < 0]
    sign = np.where(np.cumsum(flip) % 2 == 1, -1.0, 1.0)
    return Q * sign[:, None]


def report(force: np.ndarray, t: np.ndarray, demo: np.ndarray) -> dict[str, Any]:
    """The bias of the channel where the tool is free (the first and last second of each
    demonstration), as a finding the faults report carries (:func:`ccl_cli.io.faults.force_bias`)."""
    from ccl_cli.io.faults import force_bias

    return {**force_bias(force, t, demo).as_dict(t), "channel": "force (base frame)"}


def finish(data: Demonstrations, force: np.ndarray, options: DataOptions) -> Demonstrations:
    """``data`` with its base-frame ``force`` (N, 3) (its shape and values checked) and the
    channel's bias reported among the faults."""
    data = replace(data, force=force)
    data.metadata["force"] = {"frame": options.force.frame, "read": options.force.describe(),
                              **({"orientation": options.force.orientation.describe()}
                                 if options.force.orientation is not None else {})}
    data.metadata["faults"] = [*data.metadata.get("faults", []), report(force, data.t, data.demo)]
    return data


def on_stamps(data: Demonstrations, t_ns: np.ndarray, streams: list[Any], options: DataOptions, where: str,
              align: Any) -> Demonstrations:
    """``data`` — the state's samples at stamps ``t_ns`` (N,) int64 ns — with the force (and
    orientation) ``streams`` (each with ``t_ns``, ``values``, in :func:`selections`' order)
    interpolated onto those stamps by ``align`` (:func:`ccl_cli.io.streams.align`), rotated into
    the base frame; the samples outside the force's span are dropped (none in span: InputError)."""
    inside = np.ones(len(t_ns), bool)
    got: dict[str, np.ndarray] = {}
    for key, stream in zip(selections(options), streams, strict=True):
        values = check_width(stream.values, key, f"{where} ({option_path(key)})")
        if key == "orientation":
            values = continuous(values)
        at, span = align(t_ns, stream.t_ns, values)
        full = np.zeros((len(t_ns), values.shape[1]))
        full[span] = at
        got[key] = full
        inside &= span
    if not inside.any():
        raise InputError(f"{where}: the force stream ({options.force.describe()}) does not overlap the state "
                         "stream in time")
    force = base_frame(got["force"], got.get("orientation"), options.force, where)
    if not inside.all():
        data = data.subset(inside)
        force = force[inside]
        data.metadata["force_dropped_outside_span"] = int((~inside).sum())
    return finish(data, force, options)
