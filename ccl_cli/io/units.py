"""Units of the state and action dimensions where the recording does not state them.

* A ``sensor_msgs/JointState`` field named ``<joint>.position`` / ``.velocity`` / ``.effort``
  is in rad, rad/s and N m (REP 103; a prismatic joint's would be m, m/s and N — the message
  does not say which, so ccl assumes revolute, as for the arms it is used with).
* An action derived from the state (``d<name>/dt``) is in the state's unit per second.

Units a file stores (canonical HDF5 ``state_units``) are kept; a stream's ``units`` option
replaces them.
"""

from __future__ import annotations

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import ConfigError

#: sensor_msgs/JointState fields of a revolute joint.
JOINT_FIELD_UNITS = {"position": "rad", "velocity": "rad/s", "effort": "N m"}


def field_unit(name: str) -> str:
    """The unit of a ``<joint>.<field>`` name of a JointState field; "" otherwise."""
    return JOINT_FIELD_UNITS.get(name.rsplit(".", 1)[1], "") if "." in name else ""


def per_second(unit: str) -> str:
    """``unit``/s (rad → rad/s, m → m/s); "" stays unknown."""
    return f"{unit}/s" if unit else ""


def configured(units: str | list[str] | None, n: int, where: str) -> list[str] | None:
    """A stream's ``units`` option as one unit per dimension (None: not given)."""
    if units is None:
        return None
    if isinstance(units, str):
        return [units] * n
    if len(units) != n:
        raise ConfigError(f"{where}.units lists {len(units)} units for {n} dimensions")
    return list(units)


def fill_units(data: Demonstrations, state: list[str] | None = None,
               action: list[str] | None = None) -> Demonstrations:
    """``data`` with the configured units (``state``, ``action``: one per dimension) and its
    other unknown units (empty strings) filled in from the names, in place."""
    if state is not None:
        data.state_units = state
    if action is not None:
        data.action_units = action
    states = [u or field_unit(n) for n, u in zip(data.state_names, data.state_units, strict=True)]
    by_state = dict(zip(data.state_names, states, strict=True))
    actions = []
    for name, unit in zip(data.action_names, data.action_units, strict=True):
        derived = name[1:-3] if name.startswith("d") and name.endswith("/dt") else None
        actions.append(unit or field_unit(name) or (per_second(by_state.get(derived, "")) if derived else ""))
    data.state_units, data.action_units = states, actions
    return data
