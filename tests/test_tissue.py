"""FEM tissue in the laparoscopy scene (godobject_drake.tissue) and its check against contact
mechanics (godobject_drake.studies.indentation): the meshes by geometry, the scenario's checks,
the organ in a real plant under the grasper, the hard case's pop-through, Hertz."""

import math

import numpy as np
import pytest
from conftest import REPO

from godobject_drake import scenario as sc
from godobject_drake.building import build_station
from godobject_drake.simulation import simulate
from godobject_drake.studies.indentation import IndentationSetup, hertz_force, indent, layer_correction
from godobject_drake.tissue import (
    ellipsoid_tet_mesh,
    grid_tet_mesh,
    surface_triangles,
    tet_volumes,
)

RADII = (0.045, 0.03, 0.025)  # the uterus's semi-axes (models/laparoscopy/organs.sdf)
DEEP_PATH = REPO / "models" / "laparoscopy" / "deep_press_path.yaml"


def fem_scenario(cells=4, duration=1.0, path=None, **organs):
    fields = {"model": "fem", "cells": cells, **organs}
    text = f"organs: {fields}\nsimulation: {{duration_s: {duration}}}\n".replace("'", "")
    s = sc.shipped_scenario("laparoscopy", text)
    return s if path is None else sc.replace(s, **{"device.path": str(path)})


def test_box_grid_tetrahedra_fill_the_box_exactly():
    V, T = grid_tet_mesh([0.0, 0.5, 2.0], [0.0, 1.0], [-1.0, 0.0, 3.0])
    vol = tet_volumes(V, T)
    assert len(T) == 6 * 2 * 1 * 2 and vol.min() > 0
    assert vol.sum() == pytest.approx(2.0 * 1.0 * 4.0, rel=1e-12)
    # A box's boundary: 2 triangles per grid face, 2 (2·1 + 1·2 + 2·2) = 16 faces.
    assert len(surface_triangles(T)) == 2 * 16


@pytest.mark.parametrize("cells, deficit", [(4, 0.075), (8, 0.02)])
def test_ellipsoid_mesh_is_inscribed_and_closes(cells, deficit):
    V, T, surface = ellipsoid_tet_mesh(RADII, cells)
    vol = tet_volumes(V, T)
    exact = 4.0 / 3.0 * math.pi * np.prod(RADII)
    # Every vertex on or inside the ellipsoid; the surface ones on it; flat faces between
    # them cut the volume by a few per cent (7.1 % at 4 cells, 1.9 % at 8).
    level = np.sum((V / RADII) ** 2, axis=1)
    assert level.max() == pytest.approx(1.0) and np.allclose(level[surface], 1.0)
    assert vol.min() > 0 and 1.0 - deficit < vol.sum() / exact < 1.0
    # The cube's 6 c² faces, 2 triangles each; Euler: V − E + F = 2 on the closed surface.
    F = surface_triangles(T)
    assert len(F) == 12 * cells**2 and len(surface) == 6 * cells**2 + 2
    assert set(np.unique(F)) == set(surface)


def test_hertz_by_hand_and_the_layer_correction_vanishes_for_a_thick_layer():
    # (4/3) · 50 kPa / (1 − 0.45²) · √5 mm · (1 mm)^1.5 = 0.1869 N
    assert hertz_force(5e4, 0.45, 0.005, 1e-3) == pytest.approx(0.18693, rel=1e-4)
    assert layer_correction(0.45, 0.005, 1e-3, 1e3) == pytest.approx(1.0, abs=1e-5)
    # χ = √(R d)/h = 0.11 at ν = 0.45: 1 − 2 α₀ χ/π + ... with α₀ = −1.635 gives 1.128.
    assert layer_correction(0.45, 0.005, 1e-3, math.sqrt(5e-6) / 0.11) == pytest.approx(1.128, abs=2e-3)


@pytest.mark.parametrize(
    "override, words",
    [
        ("organs: {model: soft}", ["organs.model", "'soft'", "rigid", "fem", "--set organs.model=fem"]),
        ("organs: {model: fem, cells: 7}", ["organs.cells", "7", "even"]),
        ("organs: {model: fem, poissons_ratio: 0.5}", ["organs.poissons_ratio", "0.5", "[0, 0.5)"]),
        ("organs: {model: fem, youngs_modulus_pa: -1}", ["organs.youngs_modulus_pa", "-1", "> 0"]),
    ],
)
def test_bad_organs_name_the_value_the_limit_and_the_fix(override, words):
    with pytest.raises(sc.ScenarioError) as e:
        sc.shipped_scenario("laparoscopy", override)
    for word in words:
        assert word in str(e.value), (word, str(e.value))


def test_rigid_organs_stay_the_default():
    s = sc.shipped_scenario("laparoscopy")
    assert s.organs.model == "rigid"
    station = build_station(s)
    assert station.god_object.tissue is None and station.plant.deformable_model().num_bodies() == 0


def test_fem_organ_replaces_the_rigid_uterus_and_is_held_below():
    station = build_station(fem_scenario(cells=4))
    organ = station.god_object.tissue
    inspector = station.scene_graph.model_inspector()
    from pydrake.geometry import Role

    rigid = [inspector.GetName(g) for g in inspector.GetAllGeometryIds(Role.kProximity)]
    assert "pelvis::uterus" not in rigid and "pelvis::bladder" in rigid  # only the uterus is replaced
    assert station.plant.deformable_model().num_bodies() == 1
    # Held: the vertices more than 35 mm under the 50 mm tall organ's top (z < −10 mm): the
    # 4-cell grid's lowest layer and a half (z = −25, −23.4 mm and the ring at −12.5 mm...).
    held = organ.rest_W[:, 2] < organ.rest_W[:, 2].max() - 0.035
    assert organ.attached == int(held.sum()) and 0 < organ.attached < organ.vertex_count // 2


def test_fem_tissue_gives_under_the_grasper_and_pushes_it_back():
    """0.8 s of the hard case's path: the jaws reach the organ's top (75 mm under P) at
    insertion 58 mm, about 0.38 s in; by 0.8 s the interface is 20 mm past it."""
    result = simulate(build_station(fem_scenario(cells=4, duration=0.8, path=DEEP_PATH)), progress=False)
    m = result.metrics
    assert not m["diverged"]
    assert m["tissue_max_displacement_m"] > 2e-3  # the surface moved by millimetres
    assert m["tool_force_at_max_N"][2] > 0.5  # the tissue pushes the tool up
    assert m["tool_tip_inside_tissue_steps"] == 0
    assert m["max_penetration_m"] == m["tool_penetration_into_tissue_m"] < 2e-3


@pytest.mark.slow(seconds=60)
def test_hard_case_deep_push_never_pops_through():
    """The interface pushes 75 mm past the organ's top (deeper than the 50 mm organ is tall):
    the tissue deforms and the tool stays on its surface."""
    result = simulate(build_station(fem_scenario(cells=4, duration=2.5, path=DEEP_PATH)), progress=False)
    m = result.metrics
    assert not m["diverged"]
    assert m["tool_tip_inside_tissue_steps"] == 0
    assert m["tool_penetration_into_tissue_m"] < 2e-3
    assert 3e-3 < m["tissue_max_displacement_m"] < 0.025  # pressed, not through its 25 mm half height


@pytest.mark.slow(seconds=40)
def test_sphere_into_fem_block_follows_hertz():
    """A 5 mm sphere pressed 0.5 and 1 mm into a 30 × 30 × 15 mm block graded from 1 mm cells
    (E 50 kPa, ν 0.45, its bottom held): the force from Drake's contact results equals the
    actuator's reaction, and lies above Hertz corrected for the held bottom by the stated
    margins (measured +21.8 % and +10.4 %: linear tetrahedra are stiff, the more so where the
    contact radius, 1.6 and 2.2 mm, spans fewer cells; docs/guide/laparoscopy.md)."""
    setup = IndentationSetup(fine_m=1e-3, half_width_m=0.015, depth_m=0.015, growth=2.0, time_step_s=0.01)
    out = indent(setup, [0.5e-3, 1e-3])
    for d_cmd, d in zip(out["depth_cmd_m"], out["depth_m"], strict=True):
        assert d == pytest.approx(d_cmd, rel=0.01)  # the sphere went where it was sent
    assert np.allclose(out["force_contact_N"], np.abs(out["force_actuator_N"]), rtol=1e-3)
    error = out["layer_error"]
    assert 0.0 < error[0] < 0.30 and 0.0 < error[1] < 0.15, error
    assert error[1] < error[0]  # the wider contact is better resolved


def test_the_organs_mesh_folder_is_removed_when_the_process_ends():
    """The tetrahedral mesh is written to a folder of its own for Drake to read; every run left
    one in the temporary directory. It goes with the organ, or at the latest when the process
    ends (a diagram's Python systems live as long as Drake holds them, often to the end)."""
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import sys; sys.path.insert(0, 'tests')\n"
        "from test_tissue import fem_scenario\n"
        "from godobject_drake.building import build_station\n"
        "folder = build_station(fem_scenario(cells=2)).god_object.tissue.vtk_dir\n"
        "assert any(folder.glob('*.vtk'))\n"
        "print(folder)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    folder = Path(out.stdout.strip().splitlines()[-1])
    assert folder.name.startswith("godobject_tissue_") and not folder.exists()
