"""HDF5 files built in memory (ccl_cli.io.h5.image) and written by create_hdf5: the bytes a file
object receives, and large datasets written from their arrays, read back by plain h5py."""

from __future__ import annotations

import hashlib
import io

import h5py
import numpy as np
import pytest

from ccl_cli.io.h5 import image as image_module
from ccl_cli.io.h5.image import Image
from ccl_cli.io.h5.probe import open_hdf5
from ccl_cli.io.h5.seal import SEAL, USERBLOCK, create_hdf5, large_dataset, sealed


def test_image_holds_what_a_file_would(tmp_path):
    """Random writes (overlapping, touching, apart, beyond the end), reads and truncations
    give the bytes io.BytesIO gives, without storing the space never written."""
    rng = np.random.default_rng(3)
    image, plain = Image(), io.BytesIO()
    for _ in range(400):
        at = int(rng.integers(0, 5000))
        if rng.random() < 0.75:
            data = rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
            for f in (image, plain):
                f.seek(at)
                f.write(data)
        elif rng.random() < 0.5:
            got = bytearray(int(rng.integers(1, 400)))
            image.seek(at)
            plain.seek(at)
            n = image.readinto(got)
            want = plain.read(len(got))
            assert bytes(got[:n]) == want and n == len(want)
        else:
            size = int(rng.integers(0, 6000))
            image.truncate(size)
            plain.truncate(size)
        assert image.seek(0, io.SEEK_END) == plain.seek(0, io.SEEK_END)
        ends = [a + len(p) for a, p in zip(image.starts, image.parts, strict=True)]
        assert all(end <= b for end, b in zip(ends, image.starts[1:], strict=False))  # disjoint, sorted
    assert b"".join(bytes(p) for p in image.pieces()) == plain.getvalue()
    gap = Image()
    gap.seek(10**6)
    gap.write(b"x")
    assert sum(map(len, gap.parts)) == 1  # a million bytes of hole take no memory
    assert b"".join(bytes(p) for p in gap.pieces()) == bytes(10**6) + b"x"


def test_large_datasets_are_written_from_their_arrays(tmp_path, monkeypatch):
    """Arrays of DIRECT_BYTES or more never pass through libhdf5, yet the sealed file holds
    them exactly beside libhdf5's own small datasets and attributes, as h5py writes them."""
    monkeypatch.setattr(image_module, "DIRECT_BYTES", 4096)
    rng = np.random.default_rng(0)
    arrays = {"t": np.cumsum(rng.random(3000)), "x": rng.standard_normal((3000, 7)),
              "ids": rng.integers(-5, 5, (700, 3)), "small": rng.standard_normal(10)}
    written: list[int] = []
    real_write = Image.write
    monkeypatch.setattr(Image, "write", lambda self, data: written.append(len(memoryview(data))) or
                        real_write(self, data))
    out = tmp_path / "built.h5"
    with create_hdf5(out) as f:
        f.attrs["note"] = "kept"
        g = f.create_group("demos")
        for name, value in arrays.items():
            large_dataset(g, name, value)
    assert max(written) < arrays["ids"].nbytes  # libhdf5 wrote none of the large arrays
    assert sealed(out)
    raw = out.read_bytes()
    assert raw.startswith(SEAL) and raw[len(SEAL):len(SEAL) + 64].decode() == \
        hashlib.sha256(raw[USERBLOCK:]).hexdigest()
    with h5py.File(out, "r") as f:  # plain h5py: nothing of ccl's reader
        assert f.attrs["note"] == "kept"
        for name, value in arrays.items():
            got = f["demos"][name][()]
            assert got.dtype == value.dtype and np.array_equal(got, value)
    with open_hdf5(out, "file") as f:  # and ccl's checks of storage inside the file
        assert np.array_equal(f["demos/x"][()], arrays["x"])


@pytest.mark.parametrize("dtype", [">f8", "f4", "bool"])
def test_other_arrays_go_through_libhdf5(tmp_path, monkeypatch, dtype):
    """Non-native byte order, booleans (an HDF5 enumeration) or small arrays: written by
    libhdf5 as before."""
    monkeypatch.setattr(image_module, "DIRECT_BYTES", 10**9 if dtype == "f4" else 4096)
    value = np.arange(5000).astype(dtype) if dtype != "bool" else np.arange(5000) % 3 == 0
    with create_hdf5(tmp_path / "f.h5") as f:
        large_dataset(f, "v", value)
    with h5py.File(tmp_path / "f.h5", "r") as f:
        assert np.array_equal(f["v"][()], value) and f["v"].dtype == value.dtype
