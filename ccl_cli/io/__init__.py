"""Reading demonstration recordings, and writing ccl's own files: the public facade.

* :func:`read_dataset` — the ``data`` options (:class:`DataOptions`) and the files → one
  :class:`~ccl_cli.dataset.Demonstrations` and the train/test masks a canonical file
  carries; :func:`load_demonstrations` the dataset alone. Every format is one entry of the
  registry (:mod:`ccl_cli.io.registry`): canonical or config-described HDF5, MATLAB .mat
  v5/v7.3, CSV and text matrices, ROS 1 bags, ROS 2 bag directories, standalone MCAP,
  detected from the content.
* :func:`inspect_recording` — what a recording holds (``ccl inspect``).
* the canonical ``ccl-demonstrations`` HDF5 file (:func:`write_demonstrations`,
  :func:`read_demonstrations`), HDF5 opened as data only (:func:`open_hdf5`, the typed
  accessors, :func:`create_hdf5`), atomic outputs, input digests, safe YAML.

Names are imported on first use, so ``import ccl_cli.io`` costs nothing until then.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "ccl_cli.io.atomic": ("atomic_dir", "atomic_path", "check_replaceable", "clean_stale"),
    "ccl_cli.io.canonical": ("check_header", "read_demonstrations", "write_demonstrations"),
    "ccl_cli.io.files": ("expand_files", "file_hash"),
    "ccl_cli.io.h5.access": ("attr_float", "attr_int", "attr_json", "attr_str", "attr_strings", "group_of",
                             "has", "members", "numeric", "strings"),
    "ccl_cli.io.h5.probe": ("open_hdf5",),
    "ccl_cli.io.h5.seal": ("create_hdf5",),
    "ccl_cli.io.load": ("inspect_recording", "load_demonstrations", "read_dataset"),
    "ccl_cli.io.options": ("ActionOptions", "DataOptions", "DemoOptions", "StreamOptions", "TimeOptions"),
    "ccl_cli.io.reader": ("Reader", "Recording"),
    "ccl_cli.io.registry": ("FORMATS", "detect_format", "open_reader"),
    "ccl_cli.io.yamlsafe": ("read_yaml",),
}
_MODULE_OF = {name: module for module, names in _WHERE.items() for name in names}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'ccl_cli.io' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
