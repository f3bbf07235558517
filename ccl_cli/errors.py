"""The one error type of the project.

Library code raises :class:`CCLError` (or a subclass) with a message meant for the
user; only the command line turns it into an exit code. Bad input and bad configuration
(:class:`InputError`, :class:`ConfigError`) are :class:`ValueError` too, as Python and
scikit-learn raise for a bad argument: ``except ValueError`` around a ccl call catches them.
"""

from __future__ import annotations


class CCLError(Exception):
    """A user-facing failure. ``exit_code`` 2 = bad usage/input, 1 = learning failed."""

    exit_code = 2

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class InputError(CCLError, ValueError):
    """Bad input: unreadable file, missing field, wrong shapes, NaNs."""

    exit_code = 2


class OutputError(InputError):
    """An output could not be written (a full disk, a file-size limit, a read-only folder);
    nothing of it was left."""

    exit_code = 2


class ConfigError(CCLError, ValueError):
    """Bad configuration: unknown key, wrong type, inconsistent options."""

    exit_code = 2


class LearningError(CCLError):
    """A learner or evaluator could not produce a result from valid input."""

    exit_code = 1
