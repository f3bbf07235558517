"""ccl: Constraint Consistent Learning.

Learn, from demonstrations ``(x_n, u_n)``, the constraint ``A(x)`` a motion obeys,
the split ``u = v + w`` of each action into task- and null-space parts, and the
unconstrained null-space policy ``pi(x)``. See ``ALGORITHMS.md`` for the equations.
"""

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import CCLError

__version__ = "0.1.0"

__all__ = ["CCLError", "Demonstrations", "__version__"]
