"""What the page carries beyond Drake's scene (godobject_drake.systems.page): the deforming surfaces'
frames as the recording stores them, the legend, and where both go in the HTML. The browser's side
(the script replaying the frames, the legend on screen) is tests/test_browser.py's."""

import base64
import gzip
import json

import numpy as np
import pytest
from pydrake.geometry import Rgba

from godobject_drake.config import scenario as sc
from godobject_drake.station.build import build_station
from godobject_drake.systems.drawing import start_meshcat
from godobject_drake.systems.page import (
    LEGEND_ID,
    SURFACES_ID,
    DeformingSurface,
    decorate,
    legend_html,
    page_of,
    swatch,
)

TETRA = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], float)
FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.fixture
def meshcat():
    return start_meshcat(port=0)


def unpack(payload: dict) -> np.ndarray:
    """The page script's unpacking, in numpy: gunzip, int16 running sum over frames (wrapping),
    times the step, plus the rest shape. Returns (frames, n, 3) in metres."""
    n = len(payload["rest"])
    deltas = np.frombuffer(gzip.decompress(base64.b64decode(payload["frames"])), "<i2").reshape(-1, n)
    steps = np.cumsum(deltas, axis=0, dtype=np.int16)  # wraps as Int16Array does
    return (np.asarray(payload["rest"]) + payload["step"] * steps.astype(float)).reshape(len(deltas), -1, 3)


def test_a_surface_keeps_its_frames_only_while_recording_and_they_unpack_to_within_half_a_step(meshcat):
    surface = DeformingSurface(meshcat, "/test/surface", TETRA, FACES, Rgba(1, 0, 0, 1))
    surface.publish(0.0, TETRA)  # not recording: nothing kept
    assert surface.times == []
    page_of(meshcat).start_recording(max_duration_s=0.5, live=False)
    rng = np.random.default_rng(1)
    shapes = {}
    for k in range(40):
        t = k / 64
        shapes[t] = TETRA + rng.normal(0.0, 0.004, TETRA.shape)  # a few mm, frame to frame
        surface.publish(t, shapes[t])
    surface.publish(0.5, TETRA)  # the same instant twice: the last one counts
    kept = [t for t in shapes if t <= 0.5]
    assert surface.times == kept  # up to max_duration_s (32 frames of 40)
    payload = surface.payload()
    assert payload["step"] == 1e-5  # displacements under 0.32 m: 10 µm steps
    frames = unpack(payload)
    expected = np.array([TETRA if t == 0.5 else shapes[t] for t in kept])
    assert np.abs(frames - expected).max() <= 0.5e-5 + 1e-7  # half a step (and float32)


def test_jumps_past_the_int16_range_survive_the_frame_differences(meshcat):
    """Frames 0.3 m apart, one after the other: the int16 differences wrap around, and the running
    sum wraps them back (each frame itself fits: 0.3 m in 10 µm steps is 30 000)."""
    surface = DeformingSurface(meshcat, "/test/jump", TETRA, FACES, Rgba(1, 0, 0, 1))
    page_of(meshcat).start_recording(live=False)
    for k in range(6):
        surface.publish(k / 64, TETRA + (0.3 if k % 2 else -0.3))
    frames = unpack(surface.payload())
    assert np.allclose(frames - TETRA, [[[-0.3 if k % 2 == 0 else 0.3] * 3] * 4 for k in range(6)], atol=1e-5)


def test_a_surface_refuses_faces_past_its_vertices(meshcat):
    with pytest.raises(ValueError, match=r"faces index vertices 0\.\.4, but there are 4"):
        DeformingSurface(meshcat, "/test/bad", TETRA, FACES + 1, Rgba(1, 0, 0, 1))


def test_decorate_puts_the_legend_and_the_surfaces_before_the_body_end(meshcat):
    page = page_of(meshcat)
    page.add("a", swatch((1.0, 0.0, 0.0)), "red <b>means</b> stop")
    surface = DeformingSurface(meshcat, "/test/surface", TETRA, FACES, Rgba(1, 0, 0, 1))
    page.start_recording(live=False)
    surface.publish(0.0, TETRA)
    out = decorate("<html><body><script>x</script></body></html>", page)
    assert out.endswith("</body></html>")
    assert f'<div id="{LEGEND_ID}">' in out and "red &lt;b&gt;means&lt;/b&gt; stop" in out  # escaped
    tag = f'<script id="{SURFACES_ID}" type="application/json">'
    start = out.index(tag) + len(tag)
    data = json.loads(out[start : out.index("</script>", start)])
    assert [d["path"] for d in data] == ["/test/surface"] and data[0]["times"] == [0.0]
    assert decorate("<body></body>", type(page)()) == "<body></body>"  # nothing to add
    with pytest.raises(ValueError, match="no </body>"):
        decorate("<html>", page)


def test_a_scene_of_two_tools_names_each_tools_colours_in_the_legend(meshcat):
    """lego_two_hands: the legend says once what the ghost, spring and ball mean, and has a line per
    tool in its own colours (the palette's first two ghosts: blue, green)."""
    s = sc.shipped_scenario("lego_two_hands")
    build_station(s, meshcat)
    legend = legend_html(page_of(meshcat))
    once = ("faint ghost", "coupling spring", "small cross", "turning magenta", "tool left", "tool right")
    for words in once:
        assert legend.count(words) == 1, words
    rows = {row.split("<span>")[-1].split("<")[0]: row for row in legend.split('<div class="row">')[1:]}
    assert "rgba(76, 153, 255, 0.35)" in rows["tool left"]  # PALETTE[0]'s ghost, 35 % opaque
    assert "rgba(51, 204, 89, 0.35)" in rows["tool right"]  # PALETTE[1]'s
