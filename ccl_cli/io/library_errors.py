"""Failures of the bag and MCAP libraries as one line each.

The reader libraries (rosbags, mcap and its ROS support packages, and what they use:
compression, sqlite, YAML) raise their own exception classes on corrupt or truncated
input, and let built-in ones through from their parsers (struct, index, decoding errors).
:func:`library_call` and :func:`library_iter` wrap each call into a library and turn
those, and only those, into one :class:`~ccl_cli.errors.InputError` naming the file.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from ccl_cli.errors import InputError


@functools.cache
def library_errors() -> tuple[type[BaseException], ...]:
    """Exception types the bag and MCAP libraries raise on corrupt or truncated input:
    their own classes, and the built-in ones their parsers let through (struct, index,
    decoding, compression errors). Only ever caught around a library call."""
    import struct

    found: list[type[BaseException]] = [struct.error, ValueError, IndexError, KeyError, TypeError,
                                        AttributeError, UnicodeDecodeError, EOFError, OverflowError,
                                        RuntimeError, OSError, AssertionError, NotImplementedError,
                                        RecursionError, MemoryError, LookupError,
                                        SyntaxError, NameError]  # mcap-ros1/2 build message classes
    for module, names in (("rosbags.rosbag1", ["ReaderError"]), ("rosbags.rosbag2", ["ReaderError"]),
                          ("rosbags.serde", ["SerdeError"]), ("rosbags.typesys", ["TypesysError"]),
                          ("rosbags.highlevel", ["AnyReaderError"]), ("mcap.exceptions", ["McapError"]),
                          ("mcap_ros1._vendor.genpy.message", ["MessageException"]),
                          ("mcap_ros1._vendor.genmsg.base", ["InvalidMsgSpec", "MsgGenerationException"]),
                          ("mcap_ros2._vendor.rosidl_adapter.parser", ["InvalidSpecification",
                                                                       "InvalidValue"])):
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        found += [getattr(mod, n) for n in names if isinstance(getattr(mod, n, None), type)]
    return tuple(found)


#: packages whose own exception classes the readers meet (the libraries, and what they use:
#: compression and sqlite)
LIBRARY_PACKAGES = {"rosbags", "mcap", "mcap_ros1", "mcap_ros2", "zstandard", "backports", "lz4", "apsw",
                    "sqlite3", "_sqlite3", "ruamel", "yaml", "bz2", "_bz2", "zlib", "lzma", "_lzma"}


def _is_library_error(exc: BaseException) -> bool:
    return isinstance(exc, library_errors()) or \
        type(exc).__module__.split(".")[0] in LIBRARY_PACKAGES


def library_call(where: str, what: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` — a call into a reader library — with the library's
    failures (its own exception classes, or built-in ones its parsers let through)
    turned into one :class:`InputError` line (``where: cannot what (...)``). Anything
    else propagates."""
    try:
        return fn(*args, **kwargs)
    except Exception as exc:  # filtered: only the libraries' exception types are converted
        if not _is_library_error(exc):
            raise
        raise InputError(f"{where}: cannot {what} ({type(exc).__name__}: {_first_line(exc)})") from None


def library_iter(where: str, what: str, iterable: Iterable[Any]) -> Iterator[Any]:
    """Items of a library's iterator; its failures (only those raised while the
    library produces the next item, never in the caller's loop body) become InputError."""
    it = library_call(where, what, iter, iterable)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as exc:  # filtered: only the libraries' exception types are converted
            if not _is_library_error(exc):
                raise
            raise InputError(f"{where}: cannot {what} ({type(exc).__name__}: {_first_line(exc)})") from None
        yield item


def _first_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [""])[0][:200]
