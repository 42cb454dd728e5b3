"""The force cue (pseudo-haptics for a non-haptic device): the target ghost and the spring show
the coupling's stretch against its force cap, faint while tracking, solid magenta at the cap."""

import math

import msgpack
import numpy as np
import pytest
from conftest import meshcat_commands, run_scene

from godobject_drake.systems.drawing import CUE_CAP_RGBA, CUE_GHOST_RGBA, CUE_LEVELS, cue_level, cue_rgba

FPS = 64
MAX_STRETCH = 0.2  # the brick scene's force cap, as a stretch (m)


def test_cue_level_and_colour_are_monotone_and_end_at_solid_magenta():
    ratios = np.linspace(-0.5, 2.0, 101)
    levels = [cue_level(r) for r in ratios]
    assert levels[0] == 0.0 and levels[-1] == 1.0 and np.all(np.diff(levels) >= 0)
    assert cue_level(0.1) == pytest.approx(math.sqrt(0.1))  # a tenth of the cap shows at 0.32
    assert cue_rgba(0.0, CUE_GHOST_RGBA) == list(CUE_GHOST_RGBA)
    assert cue_rgba(1.0, CUE_GHOST_RGBA) == list(CUE_CAP_RGBA)
    reds = [cue_rgba(x, CUE_GHOST_RGBA)[0] for x in np.linspace(0, 1, 11)]
    alphas = [cue_rgba(x, CUE_GHOST_RGBA)[3] for x in np.linspace(0, 1, 11)]
    assert np.all(np.diff(reds) > 0) and np.all(np.diff(alphas) > 0)


def visible_levels(html, ghost: str) -> dict[int, int]:
    """Frame → the cue level shown on ``ghost``, replayed from the recording's visibility tracks."""
    (animation,) = [c for c in meshcat_commands(html.read_text()) if b"set_animation" in c]
    message = msgpack.unpackb(animation, raw=False)
    changes = []
    for a in message["animations"]:
        prefix = f"/godobject/ghost/{ghost}/cue_"
        if a["path"].startswith(prefix) and a["path"].count("/") == prefix.count("/"):
            k = int(a["path"][len(prefix) :])
            for track in a["clip"]["tracks"]:
                if track["name"] == ".visible":
                    changes += [(key["time"], k, key["value"]) for key in track["keys"]]
    shown, out = {}, {}
    for frame in range(max(t for t, _, _ in changes) + 1):
        for t, k, v in changes:
            if t == frame:
                shown[k] = v
        on = [k for k, v in shown.items() if v]
        if len(on) == 1:
            out[frame] = on[0]
    return out


@pytest.mark.slow
def test_the_recording_shows_the_stretch_the_coupling_has(tmp_path):
    """The brick path pushed through the wall: at every recorded frame the ghost shows the level
    of √(stretch / cap), stretch = |p_T − p_G| from the coupling's logged terms (a second
    reading of the same numbers), and the push reaches the top levels."""
    html = tmp_path / "lego.html"
    result = run_scene("lego", "--duration", "4", "--record", str(html))
    terms, h = result.data["terms"], 1e-3
    stretch = np.linalg.norm(terms[:, 5:8] - terms[:, 18:21], axis=1)
    levels = visible_levels(html, "brick_0/brick")
    assert len(levels) > 100

    def level(ratio):
        return round((CUE_LEVELS - 1) * cue_level(ratio))

    mismatched = []
    for frame, k in levels.items():
        # A frame at t = f/64 s falls between plant steps: the state it draws is that of the
        # step before or after it (the log has both), so either level may show at a boundary.
        step = math.floor(frame / FPS / h)
        if k not in {level(stretch[step] / MAX_STRETCH), level(stretch[step + 1] / MAX_STRETCH)}:
            mismatched.append((frame, k, stretch[step : step + 2] / MAX_STRETCH))
    assert not mismatched
    assert max(levels.values()) >= CUE_LEVELS - 2 and min(levels.values()) == 0


def test_the_cue_can_be_switched_off(tmp_path):
    html = tmp_path / "lego.html"
    run_scene("lego", "--duration", "0.2", "--record", str(html), "--force-cue", "off")
    assert b"cue_" not in b"".join(meshcat_commands(html.read_text()))
