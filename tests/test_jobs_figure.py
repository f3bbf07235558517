"""summary.png of ``ccl batch`` (render/jobs_figure.py): one row per job, every name drawn, a
value of exactly 0 and a job with no value shown (not lost on a log axis), failed jobs marked,
the height growing with the jobs — checked through what is drawn, for 40 and 400 jobs."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from ccl_cli.app.batch import JobResult
from ccl_cli.render import jobs_figure as jf
from ccl_cli.render.summary import _short, write_summary

METRICS = ["learn-a.test.NPOE", "learn-a.test.NPPE"]


def results(n: int) -> list[JobResult]:
    """n jobs: every 17th (from the 6th) failed, every 11th (from the 4th) with NPOE exactly 0,
    every 4th (from the 2nd) without NPPE, every 13th (from the 8th) skipped (kept)."""
    rng = np.random.default_rng(n)
    out = []
    for i in range(n):
        name = f"rec_{i:04d}_h5-{i:08x}"
        if i % 17 == 5:
            out.append(JobResult(name, [name], "failed", 0.1, error="learn-a: no motion"))
            continue
        test = {"NPOE": 0.0 if i % 11 == 3 else float(10 ** rng.uniform(-5, -1))}
        if i % 4 != 1:
            test["NPPE"] = float(10 ** rng.uniform(-6, 0))
        stages = {"learn-a": {"method": "auto" if i % 3 else "nhat", "n_constraints": 1, "test": test}}
        out.append(JobResult(name, [name], "skipped" if i % 13 == 7 else "ok", 1.0, stages=stages))
    return out


def jobs_of(res: list[JobResult]) -> list[jf.Job]:
    def value(r: JobResult, metric: str) -> float | None:
        return (r.stages.get("learn-a") or {}).get("test", {}).get(metric.split(".")[-1])

    return [jf.Job(_short(r.job_id, 32), r.status, " ".join(f"{s}:{e['method']}" for s, e in
                                                            r.stages.items()),
                   {m: value(r, m) for m in METRICS}) for r in res]


@pytest.mark.parametrize("n", [40, 400])
def test_every_job_is_a_named_row_with_its_value_zero_missing_or_failed(n):
    res = results(n)
    jobs = jobs_of(res)
    fig = jf.jobs_figure(jobs, METRICS)
    first = fig.axes[0]
    names = [t.get_text() for t in first.texts]
    assert names == [j.name + (" (failed)" if j.status == "failed" else "") for j in jobs]
    assert [t.get_position()[1] for t in first.texts] == list(range(n))  # job i on row i
    assert all(t.get_fontsize() >= 8 for t in first.texts)  # legible at 80 dpi
    red = [t.get_text() for t in first.texts if t.get_color() == jf.FAILED]
    assert red == [f"rec_{i:04d}_h5 (failed)" for i in range(n) if i % 17 == 5]
    for ax, metric in zip(fig.axes, METRICS, strict=True):
        drawn = {}  # row → (x, marker kind)
        for c in ax.collections:
            if not hasattr(c, "get_offsets") or hasattr(c, "get_segments"):
                continue
            kind = c.get_label() if not c.get_label().startswith("_") else "mark"
            for x, y in np.asarray(c.get_offsets()):
                assert int(y) not in drawn  # one mark per job and panel
                drawn[int(y)] = (x, kind)
        assert sorted(drawn) == list(range(n))  # every job has a mark in every panel
        left = ax.get_xlim()[0]
        for i, j in enumerate(jobs):
            x, kind = drawn[i]
            value = j.values[metric]
            if j.status == "failed" or value is None or value == 0:
                assert kind == "mark" and left < x < min(v for v in [jj.values[metric] for jj in jobs]
                                                         if v)  # at the left edge, inside the axes
            else:
                assert x == pytest.approx(value) and kind == j.method
        zeros = [i for i, j in enumerate(jobs) if j.values[metric] == 0 and j.status != "failed"]
        assert (metric == "learn-a.test.NPOE") == bool(zeros)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert {"exactly 0 (left edge)", "no value", "failed", "learn-a:auto", "learn-a:nhat"} <= set(labels)


def test_the_figure_grows_with_the_jobs(tmp_path):
    sizes = {}
    for n in (5, 40, 400):
        out = tmp_path / str(n)
        out.mkdir()
        write_summary(out, results(n), 1.0, plots=True)
        with Image.open(out / "summary.png") as png:
            sizes[n] = png.size
    for n, (_, h) in sizes.items():
        assert h == round((jf.HEAD + jf.ROW * max(n, 3) + jf.FOOT) * jf.DPI)  # 13.6 px per job
    assert sizes[40][0] == sizes[400][0]  # one width: the longest name (a failed one) and the panels
    assert sizes[5][0] < sizes[40][0]  # no job failed: no "(failed)" to make room for
    assert sizes[40][1] >= 600 and sizes[400][1] > 5000


def test_a_name_that_is_not_utf8_is_drawn():
    assert _short("caf\udce9_h5-0123abcd") == "caf\ufffd_h5"
    fig = jf.jobs_figure([jf.Job("a$b$_c", "ok", "m", {"x": 1e-3})], ["x"])
    assert fig.axes[0].texts[0].get_text() == "a$b$_c"  # as written: no math parsed
    fig.canvas.draw()
