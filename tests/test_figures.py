"""The figures' drawing helpers: the PNG files against matplotlib's own, bars and streamline
heads against the geometry they stand for, and matplotlib's import left as it was found."""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ccl_cli import lifeline
from ccl_cli.app import views
from ccl_cli.render import drawing, figures


def test_an_opaque_figure_is_written_as_rgb_and_a_transparent_one_keeps_its_alpha(tmp_path):
    fig, ax = figures.subplots(figsize=(2, 1))
    ax.plot([0, 1], [0, 1])
    figures.save_figure(fig, tmp_path / "opaque.png", dpi=50)
    fig.patch.set_alpha(0.5)
    figures.save_figure(fig, tmp_path / "alpha.png", dpi=50)
    with Image.open(tmp_path / "opaque.png") as im:
        assert im.mode == "RGB" and im.size == (100, 50)
        assert im.info["dpi"] == pytest.approx((50, 50), abs=0.02)  # stored as whole pixels per metre
    with Image.open(tmp_path / "alpha.png") as im:
        assert im.mode == "RGBA" and np.asarray(im)[0, 0, 3] < 255


def test_save_figure_writes_the_pixels_matplotlib_writes(tmp_path):
    import matplotlib

    fig, ax = figures.subplots(figsize=(3, 2))
    x = np.linspace(0, 1, 50)
    ax.plot(x, np.sin(6 * x), label="sin")
    ax.set_title("a title", y=1.0)
    ax.legend()
    figures.save_figure(fig, tmp_path / "ours.png")
    with matplotlib.rc_context(figures.RC):
        fig.savefig(tmp_path / "theirs.png", dpi=figures.DPI)
    with Image.open(tmp_path / "ours.png") as ours, Image.open(tmp_path / "theirs.png") as theirs:
        assert ours.size == theirs.size == (round(3 * figures.DPI), round(2 * figures.DPI))
        assert np.array_equal(np.asarray(ours.convert("RGB")), np.asarray(theirs.convert("RGB")))


def test_halfway_along_a_polyline_by_arc_length():
    line = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]])  # length 4: halfway is 1 up the second leg
    point, direction = figures.halfway(line)
    assert point == pytest.approx([1.0, 1.0])
    assert direction == pytest.approx([0.0, 1.0])
    point, direction = figures.halfway(np.array([[2.0, 2.0], [0.0, 0.0]]))
    assert point == pytest.approx([1.0, 1.0])
    assert direction == pytest.approx([-np.sqrt(0.5), -np.sqrt(0.5)])


def test_bars_cover_what_ax_bar_covers():
    x, h = np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.5, -1.0, 2.0, 0.0])
    fig, (ax1, ax2) = figures.subplots(1, 2, figsize=(4, 2))
    ours = figures.bars(ax1, x, h, 0.6, "tab:red")
    theirs = ax2.bar(x, h, 0.6)
    for path, rect in zip(ours.get_paths(), theirs.patches, strict=True):
        v = path.vertices[:4]
        assert v[:, 0].min() == pytest.approx(rect.get_x())
        assert v[:, 0].max() == pytest.approx(rect.get_x() + 0.6)
        assert sorted([v[:, 1].min(), v[:, 1].max()]) == pytest.approx(sorted([0.0, rect.get_height()]))
    assert ax1.get_ylim() == pytest.approx(ax2.get_ylim())
    assert ax1.get_xlim() == pytest.approx(ax2.get_xlim())


def test_one_head_per_streamline_on_the_field_figure():
    g = np.linspace(-1, 1, 22)
    G1, G2 = np.meshgrid(g, g)
    F = np.column_stack([-G2.ravel() - 0.3 * G1.ravel(), G1.ravel() - 0.3 * G2.ravel()])  # a spiral
    fig, ax = figures.subplots(figsize=(4, 4))
    figures.streamlines(ax, G1, G2, F)
    from matplotlib.collections import LineCollection
    from matplotlib.quiver import Quiver

    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    heads = [c for c in ax.collections if isinstance(c, Quiver)]
    assert len(lines) == 1 and len(heads) == 1 and len(ax.patches) == 0
    assert len(heads[0].U) == len(lines[0].get_segments()) > 10
    # each head points along the field at its position (the field is smooth: nearest grid point)
    P = heads[0].get_offsets()
    grid = np.column_stack([G1.ravel(), G2.ravel()])
    nearest = np.argmin(((P[:, None, :] - grid[None]) ** 2).sum(-1), axis=1)
    D = np.column_stack([heads[0].U, heads[0].V])
    cos = np.sum(D * F[nearest], axis=1) / np.linalg.norm(F[nearest], axis=1)
    assert np.all(cos > 0.9)


def test_matplotlib_import_shortcut_is_undone_after_the_import():
    figures._import_matplotlib()
    from matplotlib.artist import Artist
    from matplotlib.lines import Line2D

    assert Artist.__dict__["_update_set_signature_and_docstring"].__func__.__name__ == \
        "_update_set_signature_and_docstring"
    line = Line2D([0, 1], [0, 1])
    line.set(color="tab:red", linewidth=3)  # set() of a class defined during the import still works
    assert line.get_linewidth() == 3

    class Later(Line2D):  # a class defined afterwards gets matplotlib's generated set() again
        pass

    assert "linewidth" in str(Later.set.__doc__)
    from matplotlib.artist import kwdoc

    assert "linewidth" in kwdoc(Line2D)  # matplotlib's own property table, restored


def test_the_toy_run_draws_its_five_figures(tmp_path):
    from ccl_cli.cli import main

    root = Path(__file__).resolve().parent.parent
    config = root / "configs" / "toy2d_learn_pi.yaml"
    assert main(["run", str(config), "--out", str(tmp_path / "o"), "-q"]) == 0
    names = sorted(p.name for p in (tmp_path / "o" / "plots").iterdir())
    assert names == ["learn-a-constraint.png", "learn-a-field.png", "learn-a-selection.png",
                     "learn-pi-field.png", "learn-pi-time.png"]
    for name in names:
        with Image.open(tmp_path / "o" / "plots" / name) as im:
            im.load()
            assert im.size[0] > 300 and im.size[1] > 200
            assert len(np.unique(np.asarray(im).reshape(-1, 3), axis=0)) > 20  # drawn, not blank


def test_the_drawer_draws_each_stage_while_the_next_runs_and_its_files_are_ccls(tmp_path, monkeypatch):
    """A drawer started before the run gets learn-a's figures as soon as learn-a ends (before
    learn-pi has run) and draws the same bytes ccl draws itself; it ends when stopped."""
    from ccl_cli.app import stages
    from ccl_cli.app.run import execute
    from ccl_cli.config import load

    root = Path(__file__).resolve().parent.parent
    monkeypatch.chdir(root)
    cfg = load(root / "configs" / "toy2d_learn_pi.yaml")
    seen: list[tuple[list[str], list[str]]] = []  # (figures handed over, stages run by then)
    ran: list[str] = []
    learn_pi = stages.Pipeline._learn_pi

    def tracked(self, opts):
        ran.append("learn-pi")
        return learn_pi(self, opts)

    monkeypatch.setattr(stages.Pipeline, "_learn_pi", tracked)
    drawer = drawing.start_drawer()
    assert drawer is not None and drawing.start_drawer() is drawer  # one per process
    worker = drawer._workers[0]
    try:
        def on_views(views):
            seen.append(([v.name for v in views], list(ran)))
            drawing.submit_views(views)

        result = execute("run", cfg, None, on_views=on_views)
        (tmp_path / "a").mkdir()
        seconds: dict[str, float] = {}
        by_drawer = drawing.draw_views(tmp_path / "a", result.views, seconds)
    finally:
        drawing.stop_drawer()
    assert set(drawer._futures) == {rel.removeprefix("plots/") for _, rel in by_drawer}
    assert all(f.done() and f.exception() is None for f in drawer._futures.values())  # all drawn there
    assert seconds["matplotlib import"] == drawer._started.result() > 0
    assert worker.exitcode == 0 and not lifeline.pid_alive(worker.pid)  # ended with the run
    assert seen[0] == (["learn-a-field.png", "learn-a-selection.png", "learn-a-constraint.png"], [])
    assert seen[1][1] == ["learn-pi"]
    (tmp_path / "b").mkdir()
    by_ccl = drawing.draw_views(tmp_path / "b", result.views)  # no drawer: drawn here
    assert by_drawer == by_ccl and len(by_ccl) == 5
    for _, rel in by_ccl:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()


def test_a_drawer_that_died_leaves_the_figures_to_ccl(tmp_path, capfd, monkeypatch):
    import os
    import signal

    from ccl_cli.app.views import View

    views = [View(f"f{k}.png", f"figure {k}", "selection",
                  {"selection": {"n_constraints": k % 3, "NPOE": [3.0, 1.0, 2.0 + k]}, "q": 3})
             for k in range(3)]
    drawer = drawing.start_drawer()
    try:
        drawing.submit_views(views[:1])
        os.kill(drawer._workers[0].pid, signal.SIGKILL)
        drawn = drawing.draw_views(tmp_path, views)
    finally:
        drawing.stop_drawer()
    assert [rel for _, rel in drawn] == ["plots/f0.png", "plots/f1.png", "plots/f2.png"]
    for _, rel in drawn:
        with Image.open(tmp_path / rel) as im:
            assert im.size[0] > 100
    assert "Traceback" not in capfd.readouterr().err


def test_figures_too_large_to_send_are_drawn_by_ccl(tmp_path, monkeypatch):
    from ccl_cli.app.views import View

    monkeypatch.setattr(drawing, "MAX_MESSAGE", 1000)
    big = View("big.png", "big", "selection", {"selection": {"n_constraints": 1, "NPOE": list(range(3000))},
                                                 "q": 3})
    drawer = drawing.start_drawer()
    try:
        drawing.submit_views([big])
        assert drawer._futures == {}  # not sent
        drawn = drawing.draw_views(tmp_path, [big])
    finally:
        drawing.stop_drawer()
    assert drawn == [("big", "plots/big.png")] and (tmp_path / "plots" / "big.png").stat().st_size > 1000


def test_a_drawer_stopped_while_it_draws_ends_its_worker():
    from ccl_cli.app.views import View

    views = [View(f"f{k}.png", f"figure {k}", "selection",
                  {"selection": {"n_constraints": 1, "NPOE": [3.0, 1.0, 2.0 + k]}, "q": 3}) for k in range(3)]
    drawer = drawing.start_drawer()
    drawing.submit_views(views)
    drawing.stop_drawer()  # before it could import matplotlib and draw three figures: killed
    worker = drawer._workers[0]
    assert worker.exitcode is not None and not lifeline.pid_alive(worker.pid)
    assert drawing._drawer is None and all(f.done() for f in drawer._futures.values())


def test_a_long_line_is_drawn_through_its_envelope_with_the_same_pixels(tmp_path):
    """A series of 200,000 samples (with breaks) drawn through at most LINE_POINTS of them —
    each run's lowest and highest — differs from the whole series drawn by no more pixels than
    matplotlib's own path simplification makes it differ from the series drawn unsimplified."""
    import matplotlib

    rng = np.random.default_rng(3)
    y = np.cumsum(rng.standard_normal(200_000))
    y[[1000, 120_000]] = np.nan  # breaks: no line drawn across them
    x = np.arange(len(y), dtype=float)
    x[np.isnan(y)] = np.nan
    ex, ey = views.envelope(x, y)
    assert len(ey) <= views.LINE_POINTS + 3 * 2 and np.isnan(ey).sum() == 2  # a break: itself and its sides
    assert np.nanmax(ey) == np.nanmax(y) and np.nanmin(ey) == np.nanmin(y)
    assert np.all(np.diff(ex[~np.isnan(ex)]) > 0)  # in order
    short = np.arange(10.0)
    assert views.envelope(short, short)[1] is short  # short series: as they are

    def drawn(xs, ys, name, simplify=True):
        with matplotlib.rc_context({"path.simplify": simplify}):
            fig, ax = figures.subplots(figsize=(4.2, 1.5))
            ax.plot(xs, ys, color="k", lw=1.0)
            ax.set_xlim(0, len(y))
            ax.set_ylim(np.nanmin(y), np.nanmax(y))
            ax.set_axis_off()
            figures.save_figure(fig, tmp_path / f"{name}.png")
        with Image.open(tmp_path / f"{name}.png") as im:
            return np.asarray(im.convert("L"), dtype=float)

    whole, exact, thin = drawn(x, y, "whole"), drawn(x, y, "exact", False), drawn(ex, ey, "thin")
    ours, theirs = (np.abs(thin - whole) > 64).mean(), (np.abs(exact - whole) > 64).mean()
    assert (whole < 128).mean() > 0.05 and ours <= theirs


def test_a_figures_size_is_counted_without_pickling_it(monkeypatch):
    """The drawer's message limit reads the figure data's bytes (arrays, items, strings); a
    recording of 10⁶ samples is not pickled to be measured (a transient copy of it)."""
    import pickle

    from ccl_cli.dataset import Demonstrations

    d = Demonstrations(np.zeros((1000, 3)), np.ones((1000, 3)))
    args = {"d": d, "lines": {"u": ("observed u", d.U)}, "title": "x" * 10}
    counted = drawing.data_bytes(args)
    assert counted >= d.X.nbytes + d.U.nbytes + d.t.nbytes + d.demo.nbytes  # d.U once
    assert counted < d.X.nbytes + 2 * d.U.nbytes + d.t.nbytes + d.demo.nbytes
    assert 0.5 < counted / len(pickle.dumps(args, pickle.HIGHEST_PROTOCOL)) < 1.5
    dumps = []
    monkeypatch.setattr(pickle, "dumps", lambda *a, **k: dumps.append(1) or b"")
    monkeypatch.setattr(drawing, "MAX_MESSAGE", 1000)

    class Pool:
        def submit(self, *a):
            raise AssertionError("a figure over the limit was sent")

    drawer = drawing.Drawer.__new__(drawing.Drawer)
    drawer._futures, drawer._pool = {}, Pool()
    drawer.submit([("big.png", "time", args)], "png")
    assert drawer._futures == {} and not dumps


@pytest.mark.parametrize("demos,ticks", [(30, 30), (60, 60), (61, 31), (10_000, 60)])
def test_the_angle_of_each_demonstration_names_at_most_60_of_them(demos, ticks):
    """A tick per demonstration up to figures.MAX_DEMO_TICKS, every k-th beyond (matplotlib laid out
    each of the 10⁴ ticks of a 10⁶-sample toy: 56 s for one figure)."""
    angles = {k: float(k % 7) for k in range(demos)}
    fig = figures.constraint_figure({"per_demo_angle_deg": angles, "median_angle_deg": 3.0}, "per_demo")
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert len(labels) == ticks and labels[0] == "0"
    assert len(fig.axes[0].patches) + sum(len(c.get_paths()) for c in fig.axes[0].collections) >= demos
