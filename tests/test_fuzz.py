"""Fuzzing in CI (issue 8): a small, seeded budget of the mutation loop of
``benchmarks/fuzz.py`` over every reader, the config and manifest loaders and
load_model, plus hypothesis properties of the text parsers. The bar: nothing but our
own error classes, nothing slow. (The large run: ``python benchmarks/fuzz.py --cases N``.)"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ccl_cli import config as C
from ccl_cli.errors import CCLError

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

import fuzz  # noqa: E402
import writers  # noqa: E402
from tests_paths import cpu_seconds  # noqa: E402


def test_mutation_loop_small_budget():
    """Every format mutated (byte flips, truncations, zeroed blocks, structural edits),
    each case run by the real command in a forked child: no internal error, no crash,
    no case over 20 s."""
    result = fuzz.fuzz(cases=50, seed=0, timeout=20.0)
    bad = {k: result["total"][k] for k in ("internal", "crash", "timeout")}
    assert bad == {"internal": 0, "crash": 0, "timeout": 0}, result["internal_groups"]
    assert len(result["per_format"]) >= 9  # every kind of input was exercised
    assert result["total"]["error"] > 0 and result["total"]["ok"] > 0


def test_hostile_mix_small_budget():
    """The mutations of issue 20 (declared-size bombs, FIFOs and other special files,
    sparse .mat, long CSV lines, JSON messages missing keys, damaged attribute tables,
    paths outside their folder): only our error classes, no crash, nothing slow."""
    result = fuzz.fuzz(cases=60, seed=1, timeout=20.0, mix="hostile")
    bad = {k: result["total"][k] for k in ("internal", "crash", "timeout")}
    assert bad == {"internal": 0, "crash": 0, "timeout": 0}, result["internal_groups"]
    assert result["over_500MB"] == 0, result["peak_rss_mb"]
    assert result["total"]["error"] > result["total"]["ok"] > 0


def test_round4_mix_small_budget():
    """The mutations of issue 28 (ROS 1 positions outside the file, 5,000-digit integers,
    names that are not UTF-8, wide CSVs, YAML key bombs and duplicate keys): only our error
    classes, no crash, nothing slow or over 500 MB."""
    result = fuzz.fuzz(cases=60, seed=3, timeout=20.0, mix="round4")
    bad = {k: result["total"][k] for k in ("internal", "crash", "timeout")}
    assert bad == {"internal": 0, "crash": 0, "timeout": 0}, result["internal_groups"]
    assert result["over_500MB"] == 0, result["peak_rss_mb"]
    assert {"huge-int", "odd-name", "ros1-position"} <= set(result["mutations"]), result["mutations"]


@pytest.fixture(scope="module")
def csv_text(tmp_path_factory) -> str:
    path = writers.write_csv(tmp_path_factory.mktemp("csv") / "rec.csv", writers.joint_recording(n=12))
    return path.read_text()


CELLS = st.one_of(st.text(max_size=40), st.sampled_from(["1e300", "-inf", "nan", "9" * 40, "", "0x1p3",
                                                          "1_0", "١٢", "\x00", "1e-400"]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(1, 12), col=st.integers(0, 7), cell=CELLS, unit=st.sampled_from(["ns", "s", None]))
def test_any_csv_cell_is_data_or_one_error(tmp_path_factory, csv_text, row, col, cell, unit):
    from ccl_cli.io import load_demonstrations

    lines = csv_text.splitlines()
    cells = lines[row].split(",")
    cells[col] = cell.replace(",", ";").replace("\n", " ").replace("\r", " ").replace('"', "'")
    lines[row] = ",".join(cells)
    path = tmp_path_factory.mktemp("c") / "rec.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogateescape") \
        if "\ud800" not in cell else path.write_bytes(("\n".join(lines)).encode("utf-8", "replace"))
    cfg = {"files": [str(path)], "state": {"columns": ["x", "y", "z"]},
           "time": {"column": "%time", **({"unit": unit} if unit else {})}}
    try:
        data = load_demonstrations(cfg)
    except CCLError as exc:
        assert "\n" not in exc.message
    else:
        assert data.X.shape[1] == 3


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.one_of(st.text(max_size=200), st.binary(max_size=200).map(lambda b: b.decode("latin-1")),
                      st.recursive(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                                             st.text(max_size=8)),
                                   lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                           st.dictionaries(st.sampled_from(
                                                               ["data", "learn-a", "seed", "stages", "files",
                                                                "n_centres", "state", "test", "basis"]),
                                                               inner, max_size=4)),
                                   max_leaves=12).map(lambda v: __import__("yaml").safe_dump(v))))
def test_any_yaml_config_loads_or_is_one_error(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("y") / "c.yaml"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    t0 = cpu_seconds()
    try:
        cfg = C.load(path)
    except CCLError as exc:
        assert "\n" not in exc.message
    else:
        assert isinstance(cfg.raw, dict)
    assert cpu_seconds() - t0 < 2
