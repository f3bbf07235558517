"""The columnar canonical layout (format_version 2) against version 1 and h5py's own view
of the file: round trips of simulated demonstrations with ground truth and masks, version 1
still read and written on request, damaged offsets refused in one line."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from ccl_cli.errors import InputError
from ccl_cli.io import load_demonstrations, read_demonstrations, write_demonstrations
from ccl_cli.simulate import reference as sim


@pytest.fixture(scope="module")
def data():
    return sim.toy2d(n_demos=7, n_steps=25, seed=4)


def test_columns_round_trip_and_equal_version_1(tmp_path, data):
    masks = {"train": [0, 2, 3, 5], "test": [1, 6]}
    v2 = write_demonstrations(tmp_path / "v2.h5", data, time_origin_ns=123, masks=masks)
    v1 = write_demonstrations(tmp_path / "v1.h5", data, time_origin_ns=123, masks=masks, format_version=1)
    a, ia = read_demonstrations(v2)
    b, ib = read_demonstrations(v1)
    assert (ia["format_version"], ib["format_version"]) == (2, 1)
    for key in ("X", "U", "t", "demo"):
        np.testing.assert_array_equal(getattr(a, key), getattr(data, key))
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert sorted(a.truth) == sorted(data.truth)
    for key, value in data.truth.items():
        np.testing.assert_array_equal(a.truth[key], value)
    assert ia["masks"] == ib["masks"] == masks and ia["groups"] == ib["groups"]
    assert ia["time_origin_ns"] == 123
    with h5py.File(v2, "r") as f:  # what the layout promises, seen by h5py
        assert f.attrs["format_version"] == 2
        assert set(f["demos"]) == {"offsets", "name", "t0_ns", "source", "t", "x", "u", "truth"}
        offsets = f["demos/offsets"][()]
        np.testing.assert_array_equal(np.diff(offsets), np.bincount(data.demo))
        np.testing.assert_array_equal(f["demos/x"][offsets[3]:offsets[4]], data.X[data.demo == 3])
        np.testing.assert_array_equal(f["demos/t0_ns"][()],
                                      123 + np.round(data.t[offsets[:-1]] * 1e9).astype(np.int64))


def test_demonstrations_out_of_order_are_grouped(tmp_path, data):
    perm = np.argsort(data.t, kind="stable")  # samples of the demonstrations interleaved
    mixed = type(data)(X=data.X[perm], U=data.U[perm], demo=data.demo[perm] * 10 + 3, t=data.t[perm])
    back, _ = read_demonstrations(write_demonstrations(tmp_path / "m.h5", mixed))
    old, _ = read_demonstrations(write_demonstrations(tmp_path / "m1.h5", mixed, format_version=1))
    for key in ("X", "U", "t", "demo"):  # demonstrations in order of first appearance, as version 1
        np.testing.assert_array_equal(getattr(back, key), getattr(old, key))
    first = mixed.demo_ids[0]
    np.testing.assert_array_equal(back.X[back.demo == 0], mixed.X[mixed.demo == first])


def test_loader_reads_both_versions_alike(tmp_path, data):
    for v in (1, 2):
        write_demonstrations(tmp_path / f"v{v}.h5", data, format_version=v)
    a = load_demonstrations({"files": [str(tmp_path / "v1.h5")]})
    b = load_demonstrations({"files": [str(tmp_path / "v2.h5")]})
    np.testing.assert_array_equal(a.X, b.X)
    np.testing.assert_array_equal(a.demo, b.demo)


@pytest.mark.parametrize("damage, message", [
    ("offsets_gap", "offsets must rise strictly"),
    ("offsets_short", "offsets must rise strictly"),
    ("offsets_text", "must be numeric"),
    ("time_back", "not strictly increasing within demonstration 2"),
    ("names", "distinct names"),
    ("version", "version 3 is not supported"),
])
def test_damaged_columns_are_one_line(tmp_path, data, damage, message):
    path = write_demonstrations(tmp_path / "d.h5", data)
    with h5py.File(path, "r+") as f:
        g = f["demos"]
        if damage == "offsets_gap":
            o = g["offsets"][()]
            o[2] = o[1]
            g["offsets"][...] = o
        elif damage == "offsets_short":
            del g["offsets"]
            g["offsets"] = np.array([0, 10])
        elif damage == "offsets_text":
            del g["offsets"]
            g["offsets"] = np.array(["0", "1"], dtype=h5py.string_dtype())
        elif damage == "time_back":
            o = g["offsets"][()]
            t = g["t"][()]
            t[o[2] + 3] = t[o[2] + 1]
            g["t"][...] = t
        elif damage == "names":
            del g["name"]
            g["name"] = np.array(["a"] * data.n_demos, dtype=h5py.string_dtype())
        else:
            f.attrs["format_version"] = 3
    with pytest.raises(InputError, match=message) as err:
        read_demonstrations(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)
