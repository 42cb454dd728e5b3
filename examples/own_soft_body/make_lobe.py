"""Make lobe.vtk: the soft body of own_soft_body.yaml, a shape the package does not ship.

A tissue lobe 12 cm long: flat underneath (where it is fixed to the world), domed on top, 4 cm
wide at its middle and narrower at its ends, 3 cm thick at its middle and thinner at its ends. It
is a box grid of 8 x 4 x 3 cells split into tetrahedra (Kuhn's six a cell, so the faces of
neighbouring cells match), each grid point moved into the lobe's shape: 180 vertices, 576
tetrahedra, written as the legacy-ASCII VTK file Drake's RegisterDeformableBody reads. A mesh of
one's own from a segmented scan (TetGen, fTetWild, gmsh -3) goes in its place the same way.

    python examples/own_soft_body/make_lobe.py          # writes examples/own_soft_body/lobe.vtk
"""

from pathlib import Path

import numpy as np

from godobject_drake.systems.tissue import grid_tet_mesh, orient, write_vtk

LENGTH, WIDTH, THICKNESS = 0.12, 0.04, 0.03  # m


def lobe(cells=(8, 4, 3)):
    """The lobe's vertices (m, its frame: x along it, z up from its flat underside) and tetrahedra."""
    xs, ys = (np.linspace(-1.0, 1.0, n + 1) for n in cells[:2])
    zs = np.linspace(0.0, 1.0, cells[2] + 1)
    V, T = grid_tet_mesh(xs, ys, zs)
    x, y, z = V.T
    half_width = 0.5 * WIDTH * (1.0 - 0.35 * x**2)  # narrower toward the ends
    height = THICKNESS * (1.0 - 0.5 * x**2) * (1.0 - 0.3 * y**2)  # domed, thinner toward the edges
    V = np.column_stack([0.5 * LENGTH * x, half_width * y, height * z])
    return V, orient(V, T)


if __name__ == "__main__":
    V, T = lobe()
    path = write_vtk(Path(__file__).with_name("lobe.vtk"), V, T)
    print(f"wrote {path}: {len(V)} vertices, {len(T)} tetrahedra")
