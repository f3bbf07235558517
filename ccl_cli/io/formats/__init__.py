"""One reader per format, each a :class:`~ccl_cli.io.reader.Reader` with its ``inspect``:
ROS 1 bags and ROS 2 bag directories (:mod:`.bag`), standalone MCAP (:mod:`.mcap`), CSV
and text matrices (:mod:`.csv`), MATLAB .mat v5/v7.3 (:mod:`.mat`), HDF5 in the canonical
or a configured layout (:mod:`.hdf5`). :mod:`ccl_cli.io.registry` lists them."""
