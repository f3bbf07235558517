"""Progress of long steps (reading a large log, a stage), reported through one hook.

Library code says what it is doing with :func:`progress_of`; nothing is shown unless a
front end installed a :data:`Hook` with :func:`install` (the CLI does, on a terminal and
without ``-q``: :func:`terminal_hook`). So a pipe, a test or a caller of the library sees
nothing, and the library imports no display code.

    with progress_of("reading /joint_states", total_bytes) as advance:
        for chunk in chunks:
            ...
            advance(len(chunk))

A leaf: it imports nothing of ccl.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from typing import Protocol

Advance = Callable[[float], None]


class Hook(Protocol):
    """Opens a display for one step of ``total`` units; the context yields ``advance(units)``."""

    def __call__(self, label: str, total: float) -> AbstractContextManager[Advance]: ...


_HOOK: list[Hook | None] = [None]
#: displays live now on the terminal (a bar of this module, or one of the CLI's that called
#: :func:`live`): a step started meanwhile shows nothing rather than a second display
_LIVE = [0]


def live(delta: int) -> None:
    """Count a display of the front end in (+1, when it starts) or out (−1, when it stops)."""
    _LIVE[0] = max(0, _LIVE[0] + delta)


def _ignore(_: float) -> None:
    return None


def install(hook: Hook | None) -> Hook | None:
    """Make ``hook`` the display of every :func:`progress_of` (None: none); returns the
    previous one."""
    previous, _HOOK[0] = _HOOK[0], hook
    return previous


def progress_of(label: str, total: float) -> AbstractContextManager[Advance]:
    """A context yielding ``advance(units)`` for a step of ``total`` units: shown by the
    installed hook, a no-op without one."""
    hook = _HOOK[0]
    return nullcontext(_ignore) if hook is None else hook(label, total)


@contextmanager
def _rich_bar(label: str, total: float) -> Iterator[Advance]:
    if _LIVE[0]:  # another display (a stage bar) is live: this step shows nothing
        yield _ignore
        return
    from rich.console import Console
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TimeRemainingColumn

    progress = Progress(TextColumn(label), BarColumn(), DownloadColumn(), TimeRemainingColumn(),
                        console=Console(stderr=True), transient=True)
    task = progress.add_task(label, total=total)
    progress.start()
    live(+1)
    try:
        yield lambda units: progress.update(task, advance=units)
    finally:
        live(-1)
        progress.stop()


def terminal_hook(quiet: bool) -> Hook | None:
    """The rich progress bar on stderr when it is a terminal and not ``quiet``, else None."""
    if quiet or not sys.stderr.isatty():
        return None
    return _rich_bar
