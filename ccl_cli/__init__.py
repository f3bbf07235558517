"""ccl: Constraint Consistent Learning.

Learn, from demonstrations ``(x_n, u_n)``, the constraint ``A(x)`` a motion obeys,
the split ``u = v + w`` of each action into task- and null-space parts, and the
unconstrained null-space policy ``pi(x)``. See docs/methods.md for the equations.
"""

from __future__ import annotations

import os as _os
import signal as _signal
import sys as _sys
from typing import Any


def _interrupted_while_starting(signum, frame) -> None:  # noqa: ANN001
    """Ctrl-C before the ``ccl`` command is running (imports): one line, exit 130."""
    _os.write(2, b"ccl: interrupted; no partial outputs were left\n")
    _os._exit(130)


# The ``ccl`` console script imports this package first: from here until
# ``ccl_cli.cli.main`` takes over, Ctrl-C ends the process with one line and 130.
if _sys.argv and _os.path.basename(_sys.argv[0]) == "ccl" and \
        _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)

from ccl_cli.errors import CCLError  # noqa: E402 - after the Ctrl-C guard

__version__ = "0.1.0"

__all__ = ["CCLError", "Demonstrations", "__version__"]


def __getattr__(name: str) -> Any:
    """``Demonstrations`` on first use, so ``import ccl_cli`` (and ``ccl --help``) stays light."""
    if name == "Demonstrations":
        from ccl_cli.dataset import Demonstrations

        return Demonstrations
    raise AttributeError(f"module 'ccl_cli' has no attribute {name!r}")
