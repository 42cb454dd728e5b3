"""What the Meshcat page shows beyond Drake's scene: a legend, triangle surfaces that deform in a
recording, and the view (the scenario's camera, no grid, no axes).

Meshcat recordings replay transforms and properties, not a triangle mesh whose vertices move
(Drake issue #23206). A :class:`DeformingSurface` draws a surface once as a triangle mesh
(``Meshcat.SetTriangleMesh``) and keeps its vertex positions frame by frame; :func:`decorate`
(called by :func:`save_recording`) embeds them in the recording's
HTML, compactly (each frame's displacement from the rest shape as 16-bit integers, base64), with
a small script that, on each of the page's animation frames, reads the animator's time and writes
the interpolated positions into the mesh's ``geometry.attributes.position`` (normals recomputed).
Live, the surface is re-sent whole at the drawing's rate (:meth:`DeformingSurface.publish`).

The legend is collected here from the drawings (each adds what it draws: :meth:`Page.add`) and
written into the recording as HTML, top left; :func:`legend_html` is that block.
"""

from __future__ import annotations

import atexit
import base64
import dataclasses
import gzip
import html
import json
import os
import threading
import time
import weakref

import numpy as np
from pydrake.geometry import Meshcat, Rgba

from godobject_drake.outputs import write_atomically

# Each frame's displacement from the rest shape is stored as int16 steps of at least this (m):
# 10 µm, so a displacement up to 0.33 m keeps 5 µm (half a step); larger ones get coarser steps.
MIN_STEP_M = 1e-5
LEGEND_ID = "godobject-legend"
SURFACES_ID = "godobject-surfaces"


@dataclasses.dataclass(frozen=True)
class Swatch:
    """A legend entry's sample: ``rgba`` drawn as ``shape``: ``solid`` (a filled box), ``ghost``
    (a faint box), ``wire`` (an outline), ``line`` (a bar), ``dot`` (a disc), ``cross`` (a plus sign)."""

    rgba: tuple[float, float, float, float]
    shape: str = "solid"

    def css(self) -> str:
        r, g, b, a = (float(x) for x in self.rgba)
        colour = f"rgba({round(255 * r)}, {round(255 * g)}, {round(255 * b)}, {a:.2f})"
        opaque = f"rgb({round(255 * r)}, {round(255 * g)}, {round(255 * b)})"
        style = {
            "solid": f"background: {colour}",
            "ghost": f"background: {colour}; outline: 1px solid {opaque}",
            "wire": f"outline: 1px dashed {opaque}; outline-offset: -1px",
            "line": f"background: {opaque}; height: 3px; margin-top: 5px",
            "dot": f"background: {opaque}; border-radius: 50%; width: 8px; height: 8px; margin: 3px",
            "cross": f"background: linear-gradient({opaque}, {opaque}) center / 100% 2px no-repeat, "
            f"linear-gradient({opaque}, {opaque}) center / 2px 100% no-repeat",
        }[self.shape]
        return f'<span class="swatch" style="{style}"></span>'


def swatch(rgba, shape: str = "solid") -> Swatch:
    values = rgba.rgba if isinstance(rgba, Rgba) else rgba
    values = tuple(float(x) for x in values)
    return Swatch(values if len(values) == 4 else (*values, 1.0), shape)


@dataclasses.dataclass
class DeformingSurface:
    """A triangle surface drawn at ``path`` whose vertices move: drawn once at rest, then
    :meth:`publish` each frame: re-sent while the page is live, kept while it records
    (:meth:`Page.start_recording`).

    ``rest`` (n, 3) are the vertices in W, ``faces`` (m, 3) index them, outward."""

    meshcat: Meshcat
    path: str
    rest: np.ndarray
    faces: np.ndarray
    rgba: Rgba
    times: list = dataclasses.field(default_factory=list)
    frames: list = dataclasses.field(default_factory=list)

    def __post_init__(self):
        self.rest = np.asarray(self.rest, float).reshape(-1, 3)
        self.faces = np.asarray(self.faces, np.int32).reshape(-1, 3)
        if self.faces.size and not (0 <= self.faces.min() and self.faces.max() < len(self.rest)):
            raise ValueError(
                f"{self.path}: faces index vertices 0..{self.faces.max()}, but there are {len(self.rest)}"
            )
        self.page = page_of(self.meshcat)
        self.page.surfaces[self.path] = self
        self._draw(self.rest)

    def _draw(self, vertices: np.ndarray) -> None:
        self.meshcat.SetTriangleMesh(self.path, vertices.T, self.faces.T, self.rgba)

    def publish(self, t: float, vertices: np.ndarray) -> None:
        """The surface at time ``t``: re-sent to the page when live, kept when recording."""
        vertices = np.asarray(vertices, float).reshape(-1, 3)
        page = self.page
        if page.live:
            self._draw(vertices)
        if page.recording and t <= page.max_duration_s + 1e-9:
            if self.times and t <= self.times[-1]:  # the same instant published twice: the last
                while self.times and t <= self.times[-1]:
                    self.times.pop()
                    self.frames.pop()
            self.times.append(float(t))
            self.frames.append((vertices - self.rest).astype(np.float32))

    def payload(self) -> dict:
        """What the recording's script reads: the rest shape, the times, and the frames: each
        vertex's displacement from rest in int16 steps of ``step`` m, each frame less the one
        before (most vertices move little from one frame to the next), gzipped, base64."""
        frames = np.asarray(self.frames, np.float32).reshape(-1, len(self.rest), 3)
        largest = float(np.abs(frames).max()) if frames.size else 0.0
        step = max(MIN_STEP_M, largest / 32000.0)
        steps = np.round(frames / step).astype("<i2").reshape(len(frames), -1)
        # int16 differences wrap around, and the page's running sum wraps them back
        deltas = np.diff(steps, axis=0, prepend=np.zeros((1, steps.shape[1]), "<i2")).astype("<i2")
        packed = gzip.compress(deltas.tobytes(), compresslevel=9, mtime=0)
        return {
            "path": self.path,
            "rest": [round(float(x), 7) for x in self.rest.ravel()],
            "times": [round(t, 6) for t in self.times],
            "step": step,
            "frames": base64.b64encode(packed).decode("ascii"),
        }


@dataclasses.dataclass
class Page:
    """What a Meshcat page carries beyond Drake's scene (:func:`page_of`)."""

    legend: dict[str, tuple[tuple[Swatch, ...], str]] = dataclasses.field(default_factory=dict)
    surfaces: dict[str, DeformingSurface] = dataclasses.field(default_factory=dict)
    live: bool = True  # someone may watch: the surfaces are re-sent each frame
    recording: bool = False
    max_duration_s: float = np.inf
    server_thread: int | None = None  # the native id of Meshcat's websocket thread (start_server)
    made_on: int | None = None  # the thread that made the Meshcat (start_server): the only one it answers
    server_failure: str | None = None  # why Meshcat's server stopped (server_stopped), once it has

    def start_recording(self, max_duration_s: float = np.inf, live: bool = True) -> None:
        """From now on the surfaces keep their frames (up to ``max_duration_s``); ``live`` False
        (a recording nobody watches, as Meshcat's ``set_visualizations_while_recording``) stops
        re-sending them."""
        self.recording, self.max_duration_s, self.live = True, float(max_duration_s), live
        for surface in self.surfaces.values():
            surface.times.clear()
            surface.frames.clear()

    def add(self, key: str, swatches, text: str) -> None:
        """A legend line: ``swatches`` (one :class:`Swatch` or several) then ``text``; a line
        already added under ``key`` is kept as it was (the first tool's colours)."""
        swatches = (swatches,) if isinstance(swatches, Swatch) else tuple(swatches)
        self.legend.setdefault(key, (swatches, text))


_PAGES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def page_of(meshcat: Meshcat) -> Page:
    """The :class:`Page` of ``meshcat`` (made on first use, gone with the Meshcat)."""
    page = _PAGES.get(meshcat)
    if page is None:
        page = _PAGES[meshcat] = Page()
    return page


# Drake's Meshcat (1.51.1 and 1.58) catches only msgpack's type errors in a websocket message: any
# other frame it cannot parse (one byte 0xc1, a truncated map) ends its server thread, and with it
# every client, the page's controls and the recording's HTML (``StaticHtml`` raises). The thread
# then waits for the main thread to notice (any Meshcat call raises once) and logs through
# Python's logging: a process that exits before it has done so aborts (std::terminate, exit 134),
# losing whatever was not yet written. What is guarded: its table in docs/haptic_devices.md
# "Pairing: only your scene drives your device".
SERVER_STOPPED = (
    "Meshcat's server stopped during the run: a websocket client sent it a frame it could not parse "
    "(Drake's Meshcat ends its server on any malformed message: any local process or web page can "
    "send one), so the page and its controls went with it"
)
SERVER_END_S = 2.0  # how long a stopped server's thread is given to end (it logs one line)


def _tasks() -> set[str]:
    try:
        return set(os.listdir("/proc/self/task"))
    except OSError:  # not Linux: the thread is waited for by time alone (server_stopped)
        return set()


def start_server(make) -> Meshcat:
    """``make()``'s Meshcat, its websocket thread's native id noted (the one thread its constructor
    starts) so that :func:`server_stopped` can wait for that thread's end."""
    before = _tasks()
    meshcat = make()
    new = _tasks() - before
    page = page_of(meshcat)
    page.server_thread = int(next(iter(new))) if len(new) == 1 else None
    page.made_on = threading.get_ident()
    return meshcat


def server_stopped(meshcat: Meshcat) -> str | None:
    """None while ``meshcat``'s server runs; once it has stopped, why, after its thread has ended
    (so the process can exit without an abort). Said once on the page (:attr:`Page.server_failure`)."""
    page = page_of(meshcat)
    if page.server_failure is not None:
        return page.server_failure
    if page.made_on not in (None, threading.get_ident()):  # Drake aborts a call from another thread
        return None
    try:
        meshcat.port()  # raises once the websocket thread has exited, and lets it end
        return None
    except RuntimeError as e:
        page.server_failure = f"{SERVER_STOPPED} ({e})"
    if page.server_thread is None:  # a Meshcat made elsewhere, or not Linux: by time alone
        time.sleep(0.5)  # releases the GIL: the thread's last act is a line through Python's logging
    else:
        task, deadline = f"/proc/self/task/{page.server_thread}", time.monotonic() + SERVER_END_S
        while os.path.exists(task) and time.monotonic() < deadline:
            time.sleep(0.005)
    return page.server_failure


@atexit.register
def _end_stopped_servers() -> None:
    """At exit, before the interpreter goes: let the thread of any Meshcat whose server stopped end
    (Drake aborts the process otherwise, after everything was written but with exit 134)."""
    for meshcat, page in list(_PAGES.items()):
        if page.made_on == threading.get_ident():  # made here (start_server): it may be asked here
            server_stopped(meshcat)


def set_view(meshcat: Meshcat, position_m=None, target_m=None) -> None:
    """No grid (its far lines cross the sky) and no axes (0.5 m lines through a scene of
    centimetres); the camera at ``position_m`` looking at ``target_m`` when given."""
    meshcat.SetProperty("/Grid", "visible", False)
    meshcat.SetProperty("/Axes", "visible", False)
    if position_m is not None:
        meshcat.SetCameraPose(np.asarray(position_m, float), np.asarray(target_m, float))


LEGEND_CSS = f"""
#{LEGEND_ID} {{ position: fixed; left: 8px; top: 8px; max-width: 430px; padding: 6px 9px;
  background: rgba(255, 255, 255, 0.82); border-radius: 4px; font: 12px/1.35 sans-serif;
  color: #222; z-index: 10; pointer-events: none; }}
#{LEGEND_ID} b {{ display: block; margin-bottom: 3px; }}
#{LEGEND_ID} .row {{ display: flex; gap: 6px; align-items: flex-start; margin: 2px 0; }}
#{LEGEND_ID} .swatches {{ display: flex; gap: 2px; flex: none; min-width: 40px; }}
#{LEGEND_ID} .swatch {{ display: inline-block; width: 14px; height: 12px; margin-top: 1px; }}
"""


def legend_html(page: Page, title: str = "What you see") -> str:
    """The legend as an HTML block (``<div id="godobject-legend">``), empty if nothing was added."""
    if not page.legend:
        return ""
    rows = []
    for swatches, text in page.legend.values():
        samples = "".join(s.css() for s in swatches)
        rows.append(
            f'<div class="row"><span class="swatches">{samples}</span><span>{html.escape(text)}</span></div>'
        )
    block = f'<div id="{LEGEND_ID}"><b>{html.escape(title)}</b>{"".join(rows)}</div>'
    return f"<style>{LEGEND_CSS}</style>\n{block}\n"


# Replays each deforming surface: the frames are unpacked once (the browser's own gzip,
# DecompressionStream, then the running sum of the frame-to-frame differences); then on every
# animation frame the animator's time (the clip's, also after a seek and once playback ends)
# picks two stored frames, their positions are interpolated into the mesh, its normals and
# bounding sphere recomputed. The surface is shaded smooth (Meshcat draws triangle meshes flat).
SURFACES_JS = """
(function () {
  const data = JSON.parse(document.getElementById("%s").textContent);
  const animator = viewer.animator;
  let tracks = null, time = 0;
  async function unpack(s) {
    const bytes = Uint8Array.from(atob(s.frames), (c) => c.charCodeAt(0));
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
    const steps = new Int16Array(await new Response(stream).arrayBuffer());
    const n = s.rest.length;
    for (let i = n; i < steps.length; i++) steps[i] += steps[i - n];  // wraps as the int16 deltas did
    const node = viewer.scene_tree.find(s.path.split("/").filter((x) => x.length > 0).concat(["<object>"]));
    return { node: node, rest: Float32Array.from(s.rest), times: s.times, step: s.step, steps: steps,
             shown: -1 };
  }
  function frameAt(times, t) {  // the last frame at or before t (the first, before it)
    let lo = 0, hi = times.length - 1;
    if (t <= times[0]) return 0;
    if (t >= times[hi]) return hi;
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (times[mid] <= t) lo = mid; else hi = mid; }
    return lo;
  }
  function show(t) {
    if (tracks === null) return;
    for (const s of tracks) {
      const mesh = s.node.object, n = s.rest.length;
      if (!mesh || !mesh.geometry || s.times.length === 0 || t === s.shown) continue;
      const k = frameAt(s.times, t), k1 = Math.min(k + 1, s.times.length - 1);
      const span = s.times[k1] - s.times[k];
      const w = span > 0 ? Math.min(Math.max((t - s.times[k]) / span, 0), 1) : 0;
      const position = mesh.geometry.attributes.position, out = position.array;
      const a = k * n, b = k1 * n;
      for (let i = 0; i < n; i++) {
        out[i] = s.rest[i] + s.step * ((1 - w) * s.steps[a + i] + w * s.steps[b + i]);
      }
      position.needsUpdate = true;
      mesh.geometry.computeVertexNormals();
      mesh.geometry.computeBoundingSphere();
      if (mesh.material && mesh.material.flatShading) {
        mesh.material.flatShading = false;
        mesh.material.needsUpdate = true;
      }
      s.shown = t;
      viewer.set_dirty();
    }
  }
  const update = animator.update.bind(animator);
  animator.update = function () { update(); if (animator.playing) time = animator.time; show(time); };
  const seek = animator.seek.bind(animator);
  animator.seek = function (t) { seek(t); time = Math.max(0, Math.min(t, animator.duration)); show(time); };
  const reset = animator.reset.bind(animator);
  animator.reset = function () { reset(); time = 0; show(time); };
  window.godobjectSurfaces = { time: () => time, ready: false };
  Promise.all(data.map(unpack)).then((unpacked) => {
    tracks = unpacked;
    window.godobjectSurfaces.ready = true;
    show(time);
  }, (error) => console.error("godobject: the deforming surfaces could not be unpacked:", error));
})();
"""


def decorate(page_html: str, page: Page) -> str:
    """Meshcat's static HTML with the page's legend and deforming surfaces (and their script)
    inserted before ``</body>``; unchanged if there is neither."""
    legend = legend_html(page)
    surfaces = [s.payload() for s in page.surfaces.values() if s.times]
    if not legend and not surfaces:
        return page_html
    extra = legend
    if surfaces:
        data = json.dumps(surfaces, separators=(",", ":")).replace("</", "<\\/")
        extra += f'<script id="{SURFACES_ID}" type="application/json">{data}</script>\n'
        extra += f"<script>{SURFACES_JS % SURFACES_ID}</script>\n"
    at = page_html.rfind("</body>")
    if at < 0:
        raise ValueError("Meshcat's static HTML has no </body>: cannot add the legend and the surfaces")
    return page_html[:at] + extra + page_html[at:]


def save_recording(meshcat: Meshcat, path) -> int:
    """Stop and publish the recording, write Meshcat's self-contained HTML with the page's legend
    and its deforming surfaces (:func:`decorate`); return its size (bytes)."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    page = page_of(meshcat)
    page.recording = False
    text = decorate(meshcat.StaticHtml(), page)
    return write_atomically(path, text)  # all at once: never half a page
