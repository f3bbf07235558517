"""ccl_cli.io.h5.access typed reads through libhdf5 (files written by h5py), and the per-process
memory of a passed tree check following every rewrite of the file."""

import os

import h5py
import numpy as np
import pytest

from ccl_cli.errors import InputError
from ccl_cli.io.h5 import access as h5safe
from ccl_cli.io.h5.probe import open_hdf5


@pytest.fixture
def sample(tmp_path):
    path = tmp_path / "s.h5"
    rng = np.random.default_rng(0)
    with h5py.File(path, "w") as f:
        g = f.create_group("g")
        g["f64"] = rng.normal(size=(7, 3))
        g["f32_be"] = rng.normal(size=(5,)).astype(">f4")
        g["i16"] = np.arange(-4, 4, dtype=np.int16).reshape(2, 4)
        g["u64_be"] = np.array([0, 1, 2**53], dtype=">u8")
        g["empty"] = np.zeros((0, 2))
        g["text"] = np.array([b"a", b"b"])
        g["cube"] = np.ones((2, 2, 2))
        g["nan"] = np.array([1.0, np.nan])
        g.create_group("sub")["deep"] = np.arange(3.0)
        g["soft"] = h5py.SoftLink("/g/f64")
        g["chunked"] = np.linspace(0, 1, 1000)
        g["f16"] = np.array([1.5, -2.25], dtype=np.float16)
        g.create_dataset("enum", data=np.array([0, 1, 1], dtype=np.int8),
                         dtype=h5py.enum_dtype({"off": 0, "on": 1}, basetype="i1"))
        g["flags"] = np.array([True, False])
        f["g"].create_dataset("gz", data=np.arange(12.0).reshape(4, 3), compression="gzip", chunks=(2, 3))
    return path


def test_numeric_values_and_types_round_trip(sample):
    with h5py.File(sample, "r") as f:
        g = f["g"]
        for name in ("f64", "f32_be", "i16", "u64_be", "chunked", "gz", "f16", "enum"):
            got = h5safe.numeric(g, name, "w", ndim=(1, 2))
            want = np.asarray(g[name][()], dtype=np.float64)
            assert got.dtype == np.float64 and got.shape == want.shape
            np.testing.assert_array_equal(got, want)
        assert h5safe.numeric(g, "u64_be", "w", ndim=(1,))[2] == 2.0**53
        assert h5safe.numeric(g, "empty", "w").shape == (0, 2)
        np.testing.assert_array_equal(h5safe.numeric(g, "soft", "w"), g["f64"][()])  # a soft link is followed
        np.testing.assert_array_equal(h5safe.numeric(g, "sub/deep", "w", ndim=(1,)), [0.0, 1.0, 2.0])
        np.testing.assert_array_equal(h5safe.numeric(f, "g/cube", "w", ndim=(3,)), np.ones((2, 2, 2)))


@pytest.mark.parametrize(("name", "kwargs", "message"), [
    ("nope", {}, "w: nope is missing"),
    ("sub", {}, "w: sub must be a dataset, got a Group"),
    ("sub/nope", {}, "w: sub/nope is missing"),
    ("text", {}, "w: /g/text must be numeric"),
    ("cube", {}, "w: /g/cube must be 1-D or 2-D, got shape (2, 2, 2)"),
    ("nan", {}, "w: /g/nan contains NaN or inf"),
    ("flags", {}, "w: /g/flags must be numeric, got dtype bool"),
    ("f64", {"limit": 1e-3}, "w: /g/f64 holds values beyond ±0.001"),
])
def test_numeric_refusals_name_the_object(sample, name, kwargs, message):
    with h5py.File(sample, "r") as f:
        with pytest.raises(InputError) as info:
            h5safe.numeric(f["g"], name, "w", **kwargs)
        assert message in info.value.message
        if name == "nan":  # allowed when asked
            assert np.isnan(h5safe.numeric(f["g"], "nan", "w", finite=False)[1])


def test_dataset_returns_the_high_level_dataset(sample):
    with h5py.File(sample, "r") as f:
        ds = h5safe.dataset(f["g"], "f64", "w")
        assert isinstance(ds, h5py.Dataset) and ds.name == "/g/f64" and ds.shape == (7, 3)
        with pytest.raises(InputError, match="must be a dataset, got a Group"):
            h5safe.dataset(f["g"], "sub", "w")


def test_a_passed_tree_check_is_not_trusted_after_the_file_changes(sample, tmp_path):
    open_hdf5(sample).close()  # passes, and is remembered
    (tmp_path / "other.h5").write_bytes(b"")
    with h5py.File(sample, "a") as f:  # the same path, rewritten in place: a new mtime/size
        f["g/escape"] = h5py.ExternalLink(str(tmp_path / "other.h5"), "/x")
    os.utime(sample, ns=(os.stat(sample).st_atime_ns, os.stat(sample).st_mtime_ns + 1_000_000))
    with pytest.raises(InputError, match="external link"):
        open_hdf5(sample)
