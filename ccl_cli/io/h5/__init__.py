"""HDF5 read as data and written sealed.

* :mod:`~ccl_cli.io.h5.seal` — files ccl writes: atomic, with the sha256 of their content in
  the user block, so a later read knows them unchanged;
* :mod:`~ccl_cli.io.h5.probe` — :func:`~ccl_cli.io.h5.probe.open_hdf5`: nothing outside the
  file is ever read, and a file ccl did not write is parsed first in a time-limited child;
* :mod:`~ccl_cli.io.h5.access` — typed, checked reads of attributes and datasets;
* :mod:`~ccl_cli.io.h5.listing` — what a file holds, for ``ccl inspect``.
"""
