"""The recordings match their legend's words, checked without a browser (each shipped scene built
with a Meshcat on a free port, its legend and its drawing read back): one drawn surface per soft
body, a force cue no model's colour can be taken for, the device point and a sleeping body told
apart by shape, the tools listed left to right as the scene's camera sees them; and the docs'
browser pictures made by one script (analysis/recording_pictures.py) from today's scenes and
legend. What the page shows in Chromium is tests/test_browser.py's."""

import argparse
import json
import re

import numpy as np
import pytest
from conftest import REPO, load_script
from pydrake.geometry import Role

from godobject_drake import cli
from godobject_drake.config import scenario as sc
from godobject_drake.station.build import build_station
from godobject_drake.systems.drawing import CUE_CAP_RGBA, start_meshcat
from godobject_drake.systems.page import page_of

pytestmark = pytest.mark.slow  # seconds each: a scene built with its drawing

# How far apart (in RGB, each channel 0..1) the cue's colour stays from every model's: red bricks
# (0.85, 0.1, 0.1) against the cue's former pure red were 0.21 apart.
MIN_COLOUR_DISTANCE = 0.5


def built(name: str, overrides: str | None = None):
    """The shipped scene ``name`` built with a Meshcat (a free port: nobody watches), published once."""
    meshcat = start_meshcat(port=0)
    station = build_station(sc.shipped_scenario(name, overrides), meshcat)
    station.diagram.ForcedPublish(station.diagram.CreateDefaultContext())
    return station, meshcat


def model_colours(station) -> list[tuple]:
    """Each illustration geometry's diffuse colour (rgb), and None for one that has none (drawn white)."""
    inspector = station.scene_graph.model_inspector()
    out = []
    for gid in inspector.GetAllGeometryIds(Role.kIllustration):
        props = inspector.GetIllustrationProperties(gid)
        has = props.HasProperty("phong", "diffuse")
        out.append(tuple(props.GetProperty("phong", "diffuse").rgba[:3]) if has else None)
    return out


@pytest.mark.parametrize(
    ("scene", "overrides", "drake_path", "own_path"),
    [
        ("laparoscopy", "organs: {model: fem, cells: 4}", "uterus_fem", "/uterus_tissue/surface"),
        ("laparoscopy_bimanual", None, "uterus_fem", "/uterus_tissue/surface"),
        ("deformable_probe", None, "probe", "/probe/shell/0"),
    ],
)
def test_each_soft_body_is_drawn_once(scene, overrides, drake_path, own_path):
    """Drake gives a deformable body a white illustration of its own, which a recording leaves where
    the last live frame had it: under the deforming surface drawn here, z-fighting it (the FEM
    organ's recording showed white facets through the pink). Only the surface that deforms in a
    recording is drawn, and every geometry left to Drake's drawing has its colour."""
    station, meshcat = built(scene, overrides)
    assert meshcat.HasPath(own_path)
    assert not meshcat.HasPath(f"/drake/visualizer/deformable_geometries/{drake_path}")
    assert None not in model_colours(station)


def rows(meshcat) -> dict[str, list]:
    """The legend's lines: text → its swatches."""
    return {text: list(swatches) for swatches, text in page_of(meshcat).legend.values()}


@pytest.mark.parametrize("scene", sc.SHIPPED)
def test_the_force_cue_is_no_models_colour(scene):
    """The cue's colour (the legend's "turning magenta") is far from every model's colour in each
    shipped scene and from every other mark the legend names (the tools' ghosts and springs, the
    organ, a sleeping body)."""
    station, meshcat = built(scene)
    cue = np.array(CUE_CAP_RGBA[:3])
    for rgb in model_colours(station):
        assert np.linalg.norm(cue - rgb) > MIN_COLOUR_DISTANCE, (scene, rgb)
    for text, swatches in rows(meshcat).items():
        if "force cap" in text:
            assert text.startswith("turning magenta") and swatches[0].rgba[:3] == tuple(cue), text
            continue
        for s in swatches:
            assert np.linalg.norm(cue - s.rgba[:3]) > MIN_COLOUR_DISTANCE, (scene, text, s)


def test_the_device_point_and_a_sleeping_body_differ_in_shape():
    """lego: the device point is a cross (three bars), a sleeping body a ball; the legend draws
    each so (the device point was a small ball of nearly the sleeping body's blue)."""
    _, meshcat = built("lego")
    lines = rows(meshcat)
    device = next(s for text, s in lines.items() if "device point" in text)
    asleep = next(s for text, s in lines.items() if "asleep" in text)
    assert device[0].shape == "cross" and asleep[0].shape == "dot"
    assert next(t for t in lines if "device point" in t).startswith("small cross")
    assert next(t for t in lines if "asleep" in t).startswith("blue ball")
    for axis in "xyz":
        assert meshcat.HasPath(f"/godobject/device/{axis}")


def screen_x(scenario, points: np.ndarray) -> np.ndarray:
    """Each point's horizontal place in the scene's camera view (negative: left of the centre):
    Meshcat's camera at ``position_m`` looks at ``target_m`` with z up."""
    camera = scenario.visualization.camera
    eye, target = np.asarray(camera.position_m), np.asarray(camera.target_m)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    d = points - eye
    return (d @ right) / (d @ forward)


def tool_point(station, name: str) -> np.ndarray:
    """Where the tool ``name`` starts (m, W): an articulated tool's tip body at its device's first
    sample, a pose tool's device target."""
    tool = station.tools[name]
    if tool.kind == "articulated":
        arm = tool.coupling.tool
        q0 = np.asarray(tool.device.samples(0.0)[0], float)
        tip = station.plant.GetBodyByName(station.scenario.tools[name].god_object.tip_body, arm.model)
        return station.plant.EvalBodyPoseInWorld(arm.set_device_state(q0), tip).translation()
    return np.asarray(tool.device.samples(0.0)[0][1][0], float)


@pytest.mark.parametrize("scene", ["laparoscopy_bimanual", "lego_two_hands"])
def test_the_legend_lists_the_tools_as_the_camera_sees_them(scene):
    """In the scene's camera view the tool named left starts left of the tool named right, and the
    legend lists them in that order. The legend's "tool left" colour was on the screen's right in
    both: laparoscopy_bimanual's camera looked from across the table from the surgeon,
    lego_two_hands' from the bricks' side of the wall (the left hand's brick_2 at y = −0.05 drawn
    right of the right hand's brick_1 at y = +0.05). lego_two_hands' hands later stack two bricks at
    one place: their starts, each grasping its brick, are where they are apart."""
    station, meshcat = built(scene)
    names = [m.group(1) for text in rows(meshcat) if (m := re.fullmatch(r"tool (\w+)", text))]
    assert sorted(names) == ["left", "right"], names
    x = screen_x(station.scenario, np.array([tool_point(station, name) for name in names]))
    assert list(np.argsort(x)) == [0, 1], dict(zip(names, x, strict=True))
    assert names == ["left", "right"]


PICTURES = load_script("analysis/recording_pictures.py")


def embedded_pictures() -> set[str]:
    """Every ``browser_*.png`` README.md and docs/ embed (by name, without .png)."""
    pages = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    return {name for page in pages for name in re.findall(r"\b(browser_\w+)\.png", page.read_text())}


def test_one_script_makes_every_browser_picture_the_docs_embed():
    listed = {p.name for p in PICTURES.PICTURES}
    assert embedded_pictures() <= listed, embedded_pictures() - listed


@pytest.mark.parametrize("picture", PICTURES.PICTURES, ids=lambda p: p.name)
def test_each_picture_is_of_todays_scene_and_legend(picture, monkeypatch):
    """The picture's PNG says which scene file it was recorded from (its SHA-256: today's) and
    what its legend said, line by line with each swatch's colour and shape (today's scene, built
    with the picture's flags, says the same), so a picture left from before a change of the scene
    or of the drawing's words or colours fails here:
    regenerate it with ``python analysis/recording_pictures.py --only NAME``."""
    from PIL import Image

    text = Image.open(REPO / "docs" / f"{picture.name}.png").text
    assert text.get("godobject:scene_sha256") == PICTURES.scene_sha256(picture.scene), picture.name
    if picture.live:
        return  # the live page draws no legend
    monkeypatch.chdir(REPO)  # the flags' files are the clone's, relative to it
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    s, _ = cli.scenario_of(PICTURES.scene_file(picture.scene), parser.parse_args(list(picture.flags)))
    meshcat = start_meshcat(port=0)
    build_station(s, meshcat)
    today = [[line, [re.search(r'style="([^"]*)"', s.css()).group(1) for s in swatches]]
             for swatches, line in page_of(meshcat).legend.values()]  # fmt: skip
    assert json.loads(text["godobject:legend"]) == today
