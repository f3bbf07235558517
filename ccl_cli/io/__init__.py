"""Readers of demonstration recordings, one per format behind one interface.

:mod:`ccl_cli.io.registry` holds the :class:`~ccl_cli.io.registry.Reader` protocol and
the formats (canonical or config-described HDF5, MATLAB .mat v5/v7.3, CSV and text
matrices, ROS 1 bag, ROS 2 bag directory, standalone MCAP). ``detect_format`` looks at
the content, not only the suffix; ``load_demonstrations`` turns the ``data`` section of a
config into one :class:`~ccl_cli.dataset.Demonstrations`. This package only re-exports.
"""

from __future__ import annotations

from ccl_cli.io.files import expand_files, file_hash
from ccl_cli.io.h5layout import is_canonical_input
from ccl_cli.io.load import DATA_KEYS, inspect_path, load_demonstrations, load_file
from ccl_cli.io.registry import (
    BAG1_MAGIC,
    HDF5_MAGIC,
    MCAP_MAGIC,
    REGISTRY,
    Format,
    Reader,
    detect_format,
    format_names,
    open_recording,
    register,
)
from ccl_cli.io.streamfile import StreamFile, StreamSource, open_reader

FORMATS = format_names()

__all__ = [
    "BAG1_MAGIC", "DATA_KEYS", "FORMATS", "HDF5_MAGIC", "MCAP_MAGIC", "REGISTRY", "Format", "Reader",
    "StreamFile", "StreamSource", "detect_format", "expand_files", "file_hash", "format_names",
    "is_canonical_input", "inspect_path", "load_demonstrations", "load_file",
    "open_reader", "open_recording", "register",
]
