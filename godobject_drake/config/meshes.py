"""Mesh files checked before Drake reads them: indices within the file's own vertices.

Drake's mesh readers trust a mesh's indices: an OBJ whose face names vertex 400,000,000 of 4, used
as a rigid hydroelastic geometry, ended the scene with a segmentation fault (exit 139) inside
Drake (its OBJ reader warns that the index is out of bounds, and the hydroelastic mesh is built
from it anyway). :func:`check_mesh` reads the formats Drake parses as text, a line at a time, and
refuses, naming the file, the line and the fix, a face (``f``), line (``l``) or point (``p``) of
an OBJ naming a vertex, texture coordinate or normal the file does not have (0, past the count,
or a negative index reaching before the first), and a cell of a legacy-ASCII VTK volume mesh
naming a point past its ``POINTS``.

What it does not read: a binary VTK file, a glTF file (``.gltf``, ``.glb``: Drake uses them for
illustration only, through its own bounds-checked reader) and an STL or PLY (Drake does not parse
them as meshes); their content goes to Drake unchecked.
"""

from pathlib import Path

MESH_SUFFIXES = (".obj", ".vtk")
# A mesh file larger than this is refused: about two million triangles, far past what a real-time
# scene collides, and about 7 s for this check to read (9 MiB/s measured).
MAX_MESH_FILE_BYTES = 64 * 2**20


class MeshFileError(ValueError):
    """A mesh file that would make Drake read past its data; names the file, the line and the fix."""


def check_mesh(path: str | Path, where: str) -> None:
    """Refuse (:class:`MeshFileError`) a mesh file whose indices reach past its data; ``where``
    (already escaped) names it. Other suffixes: nothing to do."""
    name = str(path).lower()
    size = Path(path).stat().st_size if name.endswith(MESH_SUFFIXES) else 0
    if size > MAX_MESH_FILE_BYTES:
        raise MeshFileError(
            f"{where}: {size / 2**20:.0f} MiB, past the {MAX_MESH_FILE_BYTES // 2**20} MiB "
            "limit on a mesh (godobject_drake.config.meshes.MAX_MESH_FILE_BYTES); decimate the mesh"
        )
    if name.endswith(".obj"):
        _check_obj(Path(path), where)
    elif name.endswith(".vtk"):
        _check_vtk(Path(path), where)


_OBJ_KINDS = {b"v": "vertex", b"vt": "texture coordinate", b"vn": "normal"}
_PLURAL = {"vertex": "vertices", "texture coordinate": "texture coordinates", "normal": "normals"}
_OBJ_REFERS = (b"f", b"l", b"p")


def _check_obj(path: Path, where: str) -> None:
    counts = dict.fromkeys(_OBJ_KINDS, 0)
    largest: dict[bytes, tuple[int, int]] = {}  # kind → (largest positive index, its line)
    with path.open("rb") as f:
        for line, raw in enumerate(f, start=1):
            parts = raw.split()
            if not parts:
                continue
            if parts[0] in counts:
                counts[parts[0]] += 1
            elif parts[0] in _OBJ_REFERS:
                for ref in parts[1:]:
                    for kind, text in zip(_OBJ_KINDS, ref.split(b"/"), strict=False):
                        _obj_index(text, kind, counts, largest, line, where)
    for kind, (index, line) in largest.items():
        if index > counts[kind]:
            _obj_refuse(where, line, kind, index, counts[kind])


def _obj_index(text, kind, counts, largest, line, where) -> None:
    if not text:
        return
    try:
        index = int(text)
    except ValueError:
        return  # not a number: Drake's reader refuses the line itself
    if index > 0:  # may name a vertex written later in the file: checked at its end
        if index > largest.get(kind, (0, 0))[0]:
            largest[kind] = (index, line)
    elif index == 0 or -index > counts[kind]:  # 0 names nothing; -k the k-th last so far
        _obj_refuse(where, line, kind, index, counts[kind])


def _obj_refuse(where: str, line: int, kind: bytes, index: int, count: int):
    what = _OBJ_KINDS[kind]
    raise MeshFileError(
        f"{where}: line {line}: a face names {what} {index}, but the mesh has {count} "
        f"({_PLURAL[what]} are numbered 1 to {count}, or -1 to -{count} counting back); Drake's reader "
        "would read past them (a crash). Fix the mesh: re-export it from the modelling tool"
    )


def _check_vtk(path: Path, where: str) -> None:
    """A legacy VTK file (``# vtk DataFile``): ASCII cells checked against ``POINTS``; binary left."""
    with path.open("rb") as f:
        head = [f.readline() for _ in range(3)]
        if not head[0].startswith(b"# vtk DataFile") or head[2].strip().upper() != b"ASCII":
            return
        points, line = None, 3
        cells_left = 0  # numbers of the CELLS section still to read (count, then indices)
        connectivity = False  # VTK 5.1: OFFSETS, then CONNECTIVITY (indices only)
        for line, raw in enumerate(f, start=4):
            words = raw.split()
            if not words:
                continue
            key = words[0].upper()
            if key == b"POINTS" and len(words) > 1 and words[1].isdigit():
                points = int(words[1])
            elif key == b"CELLS" and len(words) > 2 and words[2].isdigit():
                cells_left = int(words[2])
                connectivity = False
            elif key == b"CONNECTIVITY":
                connectivity, cells_left = True, -1
            elif key in (b"OFFSETS", b"CELL_TYPES", b"CELL_DATA", b"POINT_DATA"):
                connectivity, cells_left = False, 0
            elif cells_left and points is not None:
                numbers = words if connectivity else words[1:]  # legacy: a cell's count, then its points
                for word in numbers:
                    if word.lstrip(b"-").isdigit() and not 0 <= int(word) < points:
                        _vtk_refuse(where, line, int(word), points)
                cells_left = cells_left - len(words) if cells_left > 0 else cells_left


def _vtk_refuse(where: str, line: int, index: int, points: int):
    raise MeshFileError(
        f"{where}: line {line}: a cell names point {index}, but the mesh has {points} (numbered 0 to "
        f"{points - 1}); Drake's reader would read past them. Fix the mesh: write it from its tetrahedra"
    )


def read_tet_vtk(path: str | Path, where: str):
    """The points ``(n, 3)`` and tetrahedra ``(m, 4)`` of a legacy-ASCII VTK unstructured grid of
    tetrahedra (cell type 10; file version 4.2 and older, or 5.1's ``OFFSETS``/``CONNECTIVITY``),
    as Drake's ``RegisterDeformableBody`` reads; anything else refused
    (:class:`MeshFileError`), naming ``where``, what the file is and the fix."""
    import numpy as np

    fix = (
        "write it as a legacy-ASCII VTK unstructured grid of tetrahedra (cell type 10), e.g. with "
        "godobject_drake.systems.tissue.write_vtk(path, points, tets)"
    )
    raw = Path(path).read_bytes()
    lines = raw.decode("ascii", errors="replace").splitlines()
    if len(lines) < 4 or not lines[0].startswith("# vtk DataFile") or lines[2].strip().upper() != "ASCII":
        first = (lines[0] if lines else "")[:40]
        third = (lines[2] if len(lines) > 2 else "")[:20]
        raise MeshFileError(
            f"{where}: not a legacy-ASCII VTK file (first line {first!r}, third {third!r}); {fix}"
        )
    words = " ".join(lines[3:]).split()
    upper = [w.upper() for w in words]

    def section(key: str) -> int:
        if key not in upper:
            raise MeshFileError(f"{where}: no {key} section; {fix}")
        return upper.index(key)

    if "UNSTRUCTURED_GRID" not in upper:
        raise MeshFileError(f"{where}: not an UNSTRUCTURED_GRID (a surface or image?); a soft body needs a "
                            f"volume mesh of tetrahedra: {fix}")  # fmt: skip
    try:
        i = section("POINTS")
        n = int(words[i + 1])
        V = np.array(words[i + 3 : i + 3 + 3 * n], float).reshape(n, 3)
        i = section("CELLS")
        if "OFFSETS" in upper:  # VTK 5.1 (meshio's and VTK 9's default): offsets, then the points
            j, c = upper.index("OFFSETS"), upper.index("CONNECTIVITY")
            m = int(words[i + 1]) - 1
            offsets = np.array(words[j + 2 : j + 2 + m + 1], int)
            points = np.array(words[c + 2 : c + 2 + int(offsets[-1])], int)
            sizes = np.diff(offsets)
            body = np.column_stack([sizes, points.reshape(m, -1)]).ravel() if np.all(sizes == 4) else sizes
        else:  # VTK 4.2 and older: each cell's point count, then its points
            m = int(words[i + 1])
            body = np.array(words[i + 3 : i + 3 + int(words[i + 2])], int)
        i = section("CELL_TYPES")
        types = np.array(words[i + 2 : i + 2 + m], int)
    except (ValueError, IndexError) as e:
        raise MeshFileError(f"{where}: its POINTS, CELLS or CELL_TYPES cannot be read ({e}); {fix}") from None
    if len(types) != m or np.any(types != 10):
        other = sorted(set(types.tolist()) - {10})
        raise MeshFileError(
            f"{where}: cell types {other} (5: triangles, 12: hexahedra); a soft body is tetrahedra "
            f"(type 10) only: tetrahedralize it (e.g. TetGen, fTetWild, gmsh -3), then {fix}"
        )
    if len(body) != 5 * m or np.any(body[::5] != 4):
        raise MeshFileError(f"{where}: its CELLS are not 4 points each; {fix}")
    T = body.reshape(m, 5)[:, 1:]
    if np.any(T < 0) or np.any(T >= n):
        raise MeshFileError(f"{where}: a cell names a point outside 0..{n - 1}; {fix}")
    return V, T


def check_tetrahedra(V, T, where: str) -> None:
    """Refuse inverted (negative volume) and degenerate (flat: volume under 1e-6 of its longest
    edge's cube) tetrahedra, naming the first, its volume and the fix."""
    import numpy as np

    a, b, c, d = (V[T[:, k]] for k in range(4))
    vol = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0
    edges = np.stack([b - a, c - a, d - a, c - b, d - b, d - c], axis=1)
    longest = np.linalg.norm(edges, axis=2).max(axis=1)
    flat = np.abs(vol) < 1e-6 * longest**3
    if np.any(flat):
        k = int(np.flatnonzero(flat)[0])
        raise MeshFileError(
            f"{where}: {int(flat.sum())} degenerate tetrahedra (the first, cell {k} of points "
            f"{T[k].tolist()}, has volume {vol[k]:.3g} m³ for a longest edge of {longest[k]:.3g} m); "
            "FEM cannot bend a flat tetrahedron: remesh it (TetGen -q, fTetWild) for well-shaped cells"
        )
    if np.any(vol < 0):
        k = int(np.flatnonzero(vol < 0)[0])
        raise MeshFileError(
            f"{where}: {int((vol < 0).sum())} of {len(T)} tetrahedra are inverted (the first, cell {k} of "
            f"points {T[k].tolist()}, has volume {vol[k]:.3g} m³ < 0; Drake needs "
            "(p1 − p0) × (p2 − p0) · (p3 − p0) > 0): swap two points of each (e.g. tets[:, [1, 2]] = "
            "tets[:, [2, 1]] where the volume is negative)"
        )
