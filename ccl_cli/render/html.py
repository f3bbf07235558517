"""report.html (``output: {html: true}``): report.md as one self-contained web page — its text,
tables and every figure of ``plots/`` embedded as a data URI (the same bytes as the files) —
and a 3-D view of the states that turns with the mouse.

Nothing is fetched: no external script, style sheet, font or image; the page opens from a disk
with no network. The 3-D view is a 2-D canvas drawn by a small inline script
(:data:`VIEW_SCRIPT`): the states (and the learnt constraint's rows, where learn-a drew them in
3-D) rotated by a turntable rotation — a turn ``yaw`` about the vertical z axis, then a tilt
``pitch`` about the screen's horizontal axis — and projected orthographically::

    R = R_x(pitch) · R_z(yaw),   p' = R (p − c) · s,   screen (w/2 + p'_x, h/2 − p'_z)

with c the centre of the states' bounding box and s fitting its largest side to the canvas.
Dragging turns it (0.01 rad per pixel), the wheel zooms, a double click resets, the arrow keys
turn it too; ``report.html#view=YAW,PITCH[,ZOOM]`` opens it at that view. The scene is
embedded as JSON (:func:`scene`): per demonstration its states (every ``stride``-th, at most
:data:`MAX_POINTS` in all), the names and units of the axes, and the rows at the states they
were drawn at.
"""

from __future__ import annotations

import base64
import html
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, group_rows

#: The most states the 3-D view embeds (every stride-th sample of each demonstration).
MAX_POINTS = 20000
#: Significant digits of the embedded coordinates (the view needs far fewer).
DIGITS = 7
MEDIA = {".png": "image/png", ".svg": "image/svg+xml", ".pdf": "application/pdf"}


# -- the 3-D scene -----------------------------------------------------------------------------
def scene(d: Demonstrations, trajectory: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """The 3-D view's data: the states X (N, 3) of ``d`` per demonstration, every ``stride``-th
    sample (one stride for all, so that at most MAX_POINTS are embedded), and — from the data of
    learn-a's trajectory figure (:func:`ccl_cli.app.views.trajectory_normals`: its states ``d``,
    the samples ``at`` (M,), the unit rows ``learnt`` (M, s, 3) and ``true`` or None) — the
    rows at those states, drawn 0.08 × the states' extent long. None when the states are not 3-D."""
    if d.n_state != 3 or d.n_samples == 0:
        return None
    stride = max(1, -(-d.n_samples // MAX_POINTS))
    rows = dict(zip(*group_rows(d.demo), strict=True))  # one sort, not a mask per demonstration
    demos = [{"id": int(k), "stride": stride, "points": _round(d.X[rows[k][::stride]])}
             for k in d.demo_ids]  # a loop over demonstrations
    lo, hi = d.X.min(0), d.X.max(0)
    out: dict[str, Any] = {"axes": _axis_names(d), "demos": demos, "lo": _round(lo), "hi": _round(hi),
                           "rows": None}
    if trajectory is not None and trajectory["d"].n_state == 3:
        shown = trajectory["d"]
        length = 0.08 * (float(np.max(hi - lo)) or 1.0)
        out["rows"] = {"at": _round(shown.X[trajectory["at"]]), "length": length,
                       "learnt": _round(trajectory["learnt"]),
                       "true": None if trajectory.get("true") is None else _round(trajectory["true"]),
                       "part": trajectory.get("part", "")}
    return out


def _axis_names(d: Demonstrations) -> list[str]:
    units = d.state_units or [""] * d.n_state
    return [f"{n} [{u}]" if u else n for n, u in zip(d.state_names, units, strict=True)]


def _round(a: Any) -> Any:
    """``a`` as nested lists of floats with DIGITS significant digits (JSON)."""
    arr = np.asarray(a, dtype=float)
    return np.array([float(f"{v:.{DIGITS}g}") for v in arr.ravel().tolist()]).reshape(arr.shape).tolist()


# -- markdown → HTML ---------------------------------------------------------------------------
def _inline(text: str) -> str:
    """One line of report.md's markdown (bold, code) as HTML, the rest escaped."""
    out = []
    for i, part in enumerate(re.split(r"(`[^`]*`)", text)):
        if i % 2:
            out.append(f"<code>{html.escape(part[1:-1])}</code>")
        else:
            out.append(re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", html.escape(part, quote=False)))
    return "".join(out)


def _figure(caption: str, src: str, folder: Path) -> str:
    """An image of report.md, embedded: its file's bytes as a data URI (a PDF as a link)."""
    path = folder / src
    media = MEDIA.get(path.suffix.lower(), "application/octet-stream")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    cap = html.escape(caption)
    if media == "application/pdf":
        return (f'<figure><a download="{html.escape(path.name)}" href="data:{media};base64,{data}">{cap} '
                f"(PDF)</a></figure>")
    return (f'<figure><img src="data:{media};base64,{data}" alt="{cap}" data-file="{html.escape(src)}">'
            f"<figcaption>{cap}</figcaption></figure>")


def _table(rows: list[str]) -> str:
    cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
    head, body = cells[0], [c for c in cells[2:]]
    out = ["<table><thead><tr>", *(f"<th>{_inline(c)}</th>" for c in head), "</tr></thead><tbody>"]
    for r in body:
        out += ["<tr>", *(f"<td>{_inline(c)}</td>" for c in r), "</tr>"]
    return "".join([*out, "</tbody></table>"])


def markdown_html(text: str, folder: Path) -> str:
    """report.md's markdown (headings, paragraphs, bold, code, lists, tables, images) as HTML,
    images embedded from ``folder`` (:func:`_figure`)."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        image = re.fullmatch(r"!\[(.*)\]\((.+)\)", line.strip())
        if not line.strip():
            i += 1
        elif m := re.match(r"(#{1,4}) (.*)", line):
            level = len(m.group(1))
            out.append(f"<h{level}>{_inline(m.group(2))}</h{level}>")
            i += 1
        elif image:
            out.append(_figure(image.group(1), image.group(2), folder))
            i += 1
        elif line.startswith("|"):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            out.append(_table(lines[i:j]))
            i = j
        elif re.match(r"\s*- ", line):
            j = i
            items: list[str] = []
            while j < len(lines) and re.match(r"\s*- ", lines[j]):
                nested = lines[j].startswith("  ")
                item = _inline(lines[j].strip()[2:])
                items.append(f'<li class="nested">{item}</li>' if nested else f"<li>{item}</li>")
                j += 1
            out.append("<ul>" + "".join(items) + "</ul>")
            i = j
        else:
            j = i
            while j < len(lines) and lines[j].strip() and not re.match(r"(#{1,4} |\||\s*- |!\[)", lines[j]):
                j += 1
            out.append("<p>" + " ".join(_inline(x) for x in lines[i:j]) + "</p>")
            i = j
    return "\n".join(out)


# -- the page ----------------------------------------------------------------------------------
STYLE = """body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0;font-size:90%}td,th{border:1px solid #ccc;padding:2px 6px}
th{background:#f3f3f3}figure{margin:1em 0}img{max-width:100%}figcaption{font-size:90%;color:#555}
code{background:#f3f3f3;padding:0 2px}li.nested{margin-left:1.5em}
#ccl-view{border:1px solid #ccc;cursor:grab;touch-action:none}.legend span{margin-right:1em}"""

#: The 3-D view (module docstring): reads the JSON of ``#ccl-scene`` and draws on ``#ccl-view``.
VIEW_SCRIPT = r"""(function () {
  "use strict";
  var scene = JSON.parse(document.getElementById("ccl-scene").textContent);
  var canvas = document.getElementById("ccl-view");
  var ctx = canvas.getContext("2d");
  var start = {yaw: -0.6, pitch: 0.35, zoom: 1};
  var view = {yaw: start.yaw, pitch: start.pitch, zoom: start.zoom};
  var lo = scene.lo, hi = scene.hi;
  var centre = [0, 1, 2].map(function (i) { return (lo[i] + hi[i]) / 2; });
  var extent = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
  var COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                 "#7f7f7f", "#bcbd22", "#17becf"];
  // R = R_x(pitch) . R_z(yaw): a turn about the vertical z axis, then a tilt towards the viewer
  function rotation(yaw, pitch) {
    var cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    return [[cy, -sy, 0], [cp * sy, cp * cy, -sp], [sp * sy, sp * cy, cp]];
  }
  // screen (x right, y down) and depth of a point p: orthographic, the box's largest side fills
  // 0.7 of the canvas's smaller side at zoom 1
  function project(p, R, w, h, zoom) {
    var s = 0.7 * Math.min(w, h) / extent * zoom;
    var d = [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]];
    var r = [0, 1, 2].map(function (i) { return R[i][0] * d[0] + R[i][1] * d[1] + R[i][2] * d[2]; });
    return [w / 2 + s * r[0], h / 2 - s * r[2], r[1]];
  }
  function line(a, b, R, colour, width) {
    var pa = project(a, R, canvas.width, canvas.height, view.zoom);
    var pb = project(b, R, canvas.width, canvas.height, view.zoom);
    ctx.strokeStyle = colour; ctx.lineWidth = width;
    ctx.beginPath(); ctx.moveTo(pa[0], pa[1]); ctx.lineTo(pb[0], pb[1]); ctx.stroke();
  }
  function draw() {
    var R = rotation(view.yaw, view.pitch), w = canvas.width, h = canvas.height;
    ctx.clearRect(0, 0, w, h);
    ctx.globalAlpha = 1;
    var corner = function (i) {
      return [i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]];
    };
    [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]]
      .forEach(function (e) { line(corner(e[0]), corner(e[1]), R, "#dddddd", 1); });
    [1, 2, 4].forEach(function (bit, i) {  // the axes from the box's lowest corner, named
      line(corner(0), corner(bit), R, "#888888", 1.5);
      var at = project(corner(bit), R, w, h, view.zoom);
      ctx.fillStyle = "#444444"; ctx.font = "12px sans-serif";
      ctx.fillText(scene.axes[i], at[0] + 4, at[1] - 4);
    });
    scene.demos.forEach(function (demo, k) {
      var pts = demo.points;
      if (!pts.length) { return; }
      ctx.strokeStyle = COLOURS[k % COLOURS.length]; ctx.lineWidth = 1.2; ctx.globalAlpha = 0.8;
      ctx.beginPath();
      pts.forEach(function (p, i) {
        var q = project(p, R, w, h, view.zoom);
        if (i === 0) { ctx.moveTo(q[0], q[1]); } else { ctx.lineTo(q[0], q[1]); }
      });
      ctx.stroke();
    });
    ctx.globalAlpha = 1;
    var rows = scene.rows;
    if (rows) {
      rows.at.forEach(function (p, m) {
        var arrow = function (set, colour, width, alpha) {
          ctx.globalAlpha = alpha;
          set[m].forEach(function (a) {
            line(p, [p[0] + rows.length * a[0], p[1] + rows.length * a[1], p[2] + rows.length * a[2]], R,
                 colour, width);
          });
        };
        if (rows.true) { arrow(rows.true, "#2ca02c", 4, 0.45); }
        arrow(rows.learnt, "#d62728", 1.5, 1);
      });
      ctx.globalAlpha = 1;
    }
  }
  var drag = null;
  canvas.addEventListener("pointerdown", function (e) {
    drag = {x: e.clientX, y: e.clientY, yaw: view.yaw, pitch: view.pitch};
    if (canvas.setPointerCapture) { canvas.setPointerCapture(e.pointerId); }
  });
  canvas.addEventListener("pointermove", function (e) {
    if (!drag) { return; }
    view.yaw = drag.yaw + 0.01 * (e.clientX - drag.x);
    view.pitch = Math.max(-1.5, Math.min(1.5, drag.pitch + 0.01 * (e.clientY - drag.y)));
    draw();
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("wheel", function (e) {
    e.preventDefault();
    view.zoom = Math.max(0.2, Math.min(20, view.zoom * Math.exp(-0.001 * e.deltaY)));
    draw();
  }, {passive: false});
  canvas.addEventListener("dblclick", function () {
    view.yaw = start.yaw; view.pitch = start.pitch; view.zoom = start.zoom; draw();
  });
  canvas.addEventListener("keydown", function (e) {
    var turn = {ArrowLeft: [-0.1, 0], ArrowRight: [0.1, 0], ArrowUp: [0, -0.1], ArrowDown: [0, 0.1]}[e.key];
    if (turn) {
      view.yaw += turn[0]; view.pitch = Math.max(-1.5, Math.min(1.5, view.pitch + turn[1])); draw();
    }
  });
  // a view to open at: report.html#view=YAW,PITCH[,ZOOM] (radians)
  var asked = /view=(-?[\d.]+),(-?[\d.]+)(?:,([\d.]+))?/.exec((window.location || {}).hash || "");
  if (asked) { view.yaw = +asked[1]; view.pitch = +asked[2]; view.zoom = asked[3] ? +asked[3] : 1; }
  draw();
  window.cclView = {rotation: rotation, project: project, draw: draw, view: view};
})();"""


def view_section(data: dict[str, Any] | None, why_not: str) -> str:
    """The 3-D view's section: the canvas, its legend and the scene as JSON, or why there is none."""
    if data is None:
        return f'<h2>3-D view</h2><p id="ccl-no-view">No 3-D view: {html.escape(why_not)}.</p>'
    n = sum(len(demo["points"]) for demo in data["demos"])
    stride = data["demos"][0]["stride"] if data["demos"] else 1
    said = f"{len(data['demos'])} demonstrations, {n} states" + (f" (every {stride}th sample)"
                                                                  if stride > 1 else "")
    legend = ['<span>one colour per demonstration</span>']
    if data["rows"]:
        legend.append('<span style="color:#d62728">— the learnt constraint rows</span>')
        if data["rows"]["true"] is not None:
            legend.append('<span style="color:#2ca02c">— the true rows</span>')
        legend.append(f"<span>(at {len(data['rows']['at'])} of the {html.escape(data['rows']['part'])} "
                      "states)</span>")
    blob = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    return ('<h2>3-D view of the states</h2>'
            f"<p>{html.escape(said)}; drag to turn, wheel to zoom, double-click to reset, arrow keys "
            "turn too.</p>"
            f'<canvas id="ccl-view" width="900" height="640" tabindex="0"></canvas>'
            f'<p class="legend">{"".join(legend)}</p>'
            f'<script type="application/json" id="ccl-scene">{blob}</script>'
            f"<script>{VIEW_SCRIPT}</script>")


def page(title: str, markdown: str, folder: Path, data: dict[str, Any] | None, why_not: str = "") -> str:
    """report.html: ``markdown`` (report.md) as HTML with the figures under ``folder`` embedded,
    and the 3-D view of ``data`` (:func:`scene`; None: ``why_not`` says why there is none)."""
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>\n"
            f"{markdown_html(markdown, folder)}\n{view_section(data, why_not)}\n</body></html>\n")


def run_page(title: str, markdown: str, folder: Path, d: Demonstrations, views: list[Any]) -> str:
    """report.html of a run: the 3-D view of all the states of ``d``, with learn-a's rows where
    its trajectory figure drew them (``views``)."""
    trajectory = next((v.args for v in views if v.kind == "trajectory"), None)
    data = scene(d, trajectory)
    why = "" if data is not None else f"the states have {d.n_state} dimension{'s' if d.n_state != 1 else ''}"
    return page(title, markdown, folder, data, why)
