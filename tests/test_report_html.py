"""report.html (``output: {html: true}``), tested headless: there is no browser here, so the page is
parsed (html.parser) — every figure of report.md embedded as a data URI with the same bytes as its
PNG file, the text's headings and tables there, nothing fetched from elsewhere, the 3-D scene's JSON
equal to the states read — and the inline script's maths is run in Node.js where it is installed
(the projection, the drawing calls and a mouse drag against a numpy reference). What this cannot
show: that a real browser lays the page out and paints the canvas as intended (fonts, CSS, pointer
capture, high-DPI canvases) — that was looked at by eye in headless Chromium (README, "Outputs")."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import read_demonstrations, write_demonstrations
from ccl_cli.render import html as page


class Page(HTMLParser):
    """What a browser would load: tags with their attributes, each script's text, the headings."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.scripts: list[tuple[dict[str, str | None], str]] = []
        self.headings: list[str] = []
        self._in: str | None = None
        self._attrs: dict[str, str | None] = {}
        self._text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag in ("script", "h1", "h2", "h3", "h4"):
            self._in, self._attrs, self._text = tag, dict(attrs), []

    def handle_data(self, data):
        if self._in:
            self._text.append(data)

    def handle_endtag(self, tag):
        if tag == self._in == "script":
            self.scripts.append((self._attrs, "".join(self._text)))
        elif tag == self._in:
            self.headings.append("".join(self._text))
        if tag == self._in:
            self._in = None


def run(tmp_path: Path, data, html: bool = True, extra: str = "") -> Path:
    path = write_demonstrations(tmp_path / "d.h5", data, force=True)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{files: [{path}]}}\noutput: {{html: {str(html).lower()}}}\n{extra}")
    out = tmp_path / "out"
    assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(out), "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def plane(tmp_path_factory):
    """A tracker drawn on a tilted plane (3-D states, one true row), learnt with report.html."""
    tmp = tmp_path_factory.mktemp("plane")
    d = sim.tracker_plane(duration=30.0, seed=1)
    out = run(tmp, d)
    parsed = Page()
    parsed.feed((out / "report.html").read_text())
    return out, parsed, read_demonstrations(tmp / "d.h5")[0]


def test_every_figure_of_the_report_is_embedded_with_the_files_bytes(plane):
    out, parsed, _ = plane
    report = (out / "report.md").read_text()
    wanted = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    images = [a for tag, a in parsed.tags if tag == "img"]
    assert [a["data-file"] for a in images] == wanted and len(wanted) >= 3  # time, trajectory, count...
    for a in images:
        head, data = a["src"].split(",", 1)
        assert head == "data:image/png;base64"
        raw = base64.b64decode(data, validate=True)
        assert raw[:8] == b"\x89PNG\r\n\x1a\n" and raw == (out / a["data-file"]).read_bytes()
    assert sorted(wanted) == sorted(f"plots/{p.name}" for p in (out / "plots").iterdir())
    headings = [m.group(2) for m in re.finditer(r"^(#{1,4}) (.*)$", report, flags=re.M)]
    assert parsed.headings[: len(headings)] == headings  # then the 3-D view's own
    assert sum(tag == "table" for tag, _ in parsed.tags) == report.count("\n|---")


def test_the_page_fetches_nothing(plane):
    out, parsed, _ = plane
    text = (out / "report.html").read_text()
    assert "http://" not in text and "https://" not in text and "url(" not in text and "@import" not in text
    for tag, attrs in parsed.tags:
        assert tag not in ("link", "iframe", "object", "embed")
        for key in ("src", "href"):
            assert attrs.get(key) is None or attrs[key].startswith("data:")
    assert all(not attrs.get("src") for attrs, _ in parsed.scripts)  # inline scripts only


def test_the_3d_scene_is_the_states_read_with_the_learnt_rows(plane):
    """The JSON holds every demonstration's states (every stride-th, to 7 digits), the axis names
    with units and, where learn-a drew them, its rows: unit, at states of the data, and normal to
    the file's plane (the true row) within a few degrees."""
    out, parsed, d = plane
    (scene_text,) = [text for attrs, text in parsed.scripts if attrs.get("id") == "ccl-scene"]
    scene = json.loads(scene_text)
    names = zip(d.state_names, d.state_units, strict=True)
    assert scene["axes"] == [f"{n} [{u}]" if u else n for n, u in names]
    assert [demo["id"] for demo in scene["demos"]] == [int(k) for k in d.demo_ids]
    for demo in scene["demos"]:
        want = d.X[d.demo == demo["id"]][:: demo["stride"]]
        assert np.asarray(demo["points"]) == pytest.approx(want, rel=1e-6, abs=1e-12)
    assert scene["lo"] == pytest.approx(d.X.min(0), rel=1e-6)
    assert scene["hi"] == pytest.approx(d.X.max(0), rel=1e-6)
    rows = scene["rows"]
    learnt, at = np.asarray(rows["learnt"]), np.asarray(rows["at"])
    assert learnt.shape[1:] == (1, 3) and np.linalg.norm(learnt, axis=-1) == pytest.approx(1.0, abs=1e-6)
    nearest = np.min(np.linalg.norm(at[:, None, :] - d.X[None], axis=-1), axis=1)
    assert nearest.max() < 1e-6 * np.abs(d.X).max()  # drawn at states of the data
    true = d.truth_per_sample("A")[0, 0] / np.linalg.norm(d.truth_per_sample("A")[0, 0])
    assert np.degrees(np.arccos(np.abs(learnt[:, 0] @ true))).max() < 5.0
    assert rows["length"] == pytest.approx(0.08 * np.max(d.X.max(0) - d.X.min(0)))


def test_states_not_in_3d_have_no_view_and_say_why(tmp_path):
    out = run(tmp_path, sim.toy2d(n_demos=8, seed=2))
    parsed = Page()
    parsed.feed((out / "report.html").read_text())
    assert not any(tag == "canvas" for tag, _ in parsed.tags) and not parsed.scripts
    assert "No 3-D view: the states have 2 dimensions." in (out / "report.html").read_text()
    assert len([t for t, _ in parsed.tags if t == "img"]) == len(list((out / "plots").iterdir()))


def test_no_page_unless_asked(tmp_path):
    out = run(tmp_path, sim.toy2d(n_demos=6, seed=2), html=False)
    assert (out / "report.md").exists() and not (out / "report.html").exists()


def test_markdown_of_the_report_as_html():
    assert page._inline("**ok** a < b `x<y` and **c**") == \
        "<strong>ok</strong> a &lt; b <code>x&lt;y</code> and <strong>c</strong>"
    text = "# T\n\n- a\n  - b\n\n| x | y |\n|---|---|\n| 1 | **2** |\n\ntext\nmore\n"
    got = page.markdown_html(text, Path("."))
    assert got == ("<h1>T</h1>\n<ul><li>a</li><li class=\"nested\">b</li></ul>\n<table><thead><tr><th>x</th>"
                   "<th>y</th></tr></thead><tbody><tr><td>1</td><td><strong>2</strong></td></tr></tbody></table>\n"
                   "<p>text more</p>")


# -- the inline script, run in Node.js -----------------------------------------------------------
HARNESS = r"""
const fs = require("fs");
const sceneText = fs.readFileSync(process.argv[2], "utf8");
const script = fs.readFileSync(process.argv[3], "utf8");
let calls = [];
const state = {};
const ctx = new Proxy(state, {
  get: (t, k) => (k in t ? t[k] : (...a) => calls.push([k, ...a])),
  set: (t, k, v) => { t[k] = v; return true; },
});
const listeners = {};
const canvas = {width: 900, height: 640, getContext: () => ctx, setPointerCapture: () => {},
                addEventListener: (name, f) => { listeners[name] = f; }};
global.document = {getElementById: (id) => (id === "ccl-scene" ? {textContent: sceneText} : canvas)};
global.window = {};
new Function(script)();
const v = window.cclView;
const lines = () => calls.filter((c) => c[0] === "moveTo" || c[0] === "lineTo");
const out = {start: {...v.view}, first: lines(), listeners: Object.keys(listeners).sort()};
const P = [[0.1, -0.2, 0.3], [1, 2, 3]];
out.rotation = v.rotation(0.7, -0.4);
out.project = P.map((p) => v.project(p, v.rotation(0.7, -0.4), 900, 640, 1.5));
calls = [];
listeners.pointerdown({clientX: 100, clientY: 100, pointerId: 1});
listeners.pointermove({clientX: 150, clientY: 80});
listeners.pointerup({});
out.dragged = {...v.view};
out.after = lines();
listeners.wheel({deltaY: -500, preventDefault: () => {}});
out.zoomed = v.view.zoom;
listeners.dblclick({});
out.reset = {...v.view};
global.window = {location: {hash: "#view=0.3,-0.2,2"}};  // a page opened at a view
new Function(script)();
out.asked = {...window.cclView.view};
console.log(JSON.stringify(out));
"""


def rotation(yaw: float, pitch: float) -> np.ndarray:
    """Turn by yaw about z, then tilt by pitch about x (the script's R, built independently)."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    return Rx @ Rz


def projected(P: np.ndarray, scene: dict, yaw: float, pitch: float, zoom: float, w=900, h=640) -> np.ndarray:
    lo, hi = np.asarray(scene["lo"]), np.asarray(scene["hi"])
    s = 0.7 * min(w, h) / np.max(hi - lo) * zoom
    r = (np.asarray(P) - (lo + hi) / 2) @ rotation(yaw, pitch).T
    return np.column_stack([w / 2 + s * r[:, 0], h / 2 - s * r[:, 2]])


def expected_lines(scene: dict, yaw: float, pitch: float, zoom: float) -> np.ndarray:
    """The (x, y) of every moveTo / lineTo of one drawing, in order: the box's 12 edges, the 3
    axes, each demonstration's polyline, then at each arrow state the true and learnt rows."""
    lo, hi = np.asarray(scene["lo"]), np.asarray(scene["hi"])
    corner = [np.where([i & 1, i & 2, i & 4], hi, lo) for i in range(8)]
    pts = []
    for a, b in [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6),
                 (3, 7), (0, 1), (0, 2), (0, 4)]:
        pts += [corner[a], corner[b]]
    for demo in scene["demos"]:
        pts += list(np.asarray(demo["points"]))
    rows = scene["rows"]
    for m, p in enumerate(rows["at"] if rows else []):
        for key in ("true", "learnt"):
            for a in (rows[key][m] if rows[key] is not None else []):
                pts += [np.asarray(p), np.asarray(p) + rows["length"] * np.asarray(a)]
    return projected(np.array(pts), scene, yaw, pitch, zoom)


@pytest.mark.skipif(shutil.which("node") is None, reason="needs Node.js to run the page's script")
def test_the_script_projects_draws_and_turns_as_the_numpy_reference(plane, tmp_path):
    out, parsed, _ = plane
    (scene_text,) = [text for attrs, text in parsed.scripts if attrs.get("id") == "ccl-scene"]
    (script,) = [text for attrs, text in parsed.scripts if not attrs]
    (tmp_path / "scene.json").write_text(scene_text)
    (tmp_path / "view.js").write_text(script)
    (tmp_path / "harness.js").write_text(HARNESS)
    proc = subprocess.run(["node", str(tmp_path / "harness.js"), str(tmp_path / "scene.json"),
                           str(tmp_path / "view.js")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    scene = json.loads(scene_text)
    assert got["listeners"] == ["dblclick", "keydown", "pointerdown", "pointermove", "pointerup", "wheel"]
    assert np.asarray(got["rotation"]) == pytest.approx(rotation(0.7, -0.4), abs=1e-12)
    P = np.array([[0.1, -0.2, 0.3], [1, 2, 3]])
    assert np.asarray(got["project"])[:, :2] == pytest.approx(projected(P, scene, 0.7, -0.4, 1.5), abs=1e-9)
    start = got["start"]
    first = np.array([c[1:] for c in got["first"]], dtype=float)
    assert first == pytest.approx(expected_lines(scene, start["yaw"], start["pitch"], 1.0), abs=1e-6)
    # a drag of 50 px right and 20 px up turns it 0.5 rad about z and tilts it -0.2 rad
    assert got["dragged"]["yaw"] == pytest.approx(start["yaw"] + 0.5)
    assert got["dragged"]["pitch"] == pytest.approx(start["pitch"] - 0.2)
    after = np.array([c[1:] for c in got["after"]], dtype=float)
    turned = expected_lines(scene, start["yaw"] + 0.5, start["pitch"] - 0.2, 1.0)
    assert after == pytest.approx(turned, abs=1e-6)
    assert not np.allclose(after, first)
    assert got["zoomed"] == pytest.approx(np.exp(0.5)) and got["reset"] == start
    assert got["asked"] == {"yaw": 0.3, "pitch": -0.2, "zoom": 2}
