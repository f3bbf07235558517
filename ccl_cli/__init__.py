"""ccl: Constraint Consistent Learning.

Learn, from demonstrations ``(x_n, u_n)``, the constraint ``A(x)`` a motion obeys,
the split ``u = v + w`` of each action into task- and null-space parts, and the
unconstrained null-space policy ``pi(x)``. See docs/methods.md for the equations.
"""

from __future__ import annotations

from typing import Any

from ccl_cli.errors import CCLError

__version__ = "0.1.0"

__all__ = ["CCLError", "Demonstrations", "__version__"]


def __getattr__(name: str) -> Any:
    """``Demonstrations`` on first use, so ``import ccl_cli`` (and ``ccl --help``) stays light."""
    if name == "Demonstrations":
        from ccl_cli.dataset import Demonstrations

        return Demonstrations
    raise AttributeError(f"module 'ccl_cli' has no attribute {name!r}")
