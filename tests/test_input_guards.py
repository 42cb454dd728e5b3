"""The input guards issue 55 added, at their limits, fast (mutation testing's tests for them).

Each bound is met exactly (passes) and passed by one (refused, the message's numbers checked):
the YAML bounds (``config.yaml_guard``: depth as written and through aliases, nodes aliases add,
size, a key twice, a cycle), the mesh indices (``config.meshes``: each OBJ index kind, forward and
backward references, VTK cells, the size), the key checks (``link.keys``: a key given as a path,
a missing named file) and the driver's output checks (``driver.process``: ``--log`` and
``--summary`` before the device is opened, a log that can no longer grow). The numbers are
counted by hand from the texts built here. ``tests/test_bad_files.py`` runs the same guards
through the command line; ``tests/test_fuzz.py`` fuzzes the first two.
"""

import fcntl
import os
import stat

import numpy as np
import pytest

from godobject_drake.config.meshes import MAX_MESH_FILE_BYTES, MeshFileError, check_mesh
from godobject_drake.config.yaml_guard import (
    MAX_ALIAS_NODES,
    MAX_YAML_BYTES,
    MAX_YAML_DEPTH,
    YamlShapeError,
    check_yaml,
    check_yaml_file,
    shown,
)
from godobject_drake.driver.process import BadInput, Driver, check_summary, open_log_file
from godobject_drake.link.keys import KEY_ENV, KeyFileError, key_path, load_key

# -- YAML ----------------------------------------------------------------------------------------------------


def test_shown_escapes_control_characters_only():
    assert shown("plain é ω") == "plain é ω"
    assert shown("a\x1b[31mb\nc\td") == "a\\x1b[31mb\\nc\\td"
    assert shown("C:\\new\x1b") == "C:\\new\\x1b"  # a backslash kept as it is, once
    assert shown(7) == "7"


def nested(levels: int) -> str:
    """A mapping (depth 1) with ``c`` at line 3 holding ``levels`` nested flow sequences (depths 2 to
    ``levels + 1``)."""
    return "a: 1\nb: 2\nc: " + "[" * levels + "]" * levels + "\n"


def test_nesting_exactly_at_the_limit_passes_and_one_more_is_refused_at_its_line():
    check_yaml(nested(MAX_YAML_DEPTH - 1), "f.yaml")
    with pytest.raises(YamlShapeError) as e:
        check_yaml(nested(MAX_YAML_DEPTH), "f.yaml")
    assert str(e.value).startswith(f"f.yaml: line 3: nested more than {MAX_YAML_DEPTH} deep (the limit")


def through_alias(height: int, at: int) -> str:
    """``a`` anchors ``height`` nested sequences (depths 2 to ``height + 1``); ``b`` (line 2) holds
    ``at`` sequences around an alias of it, which expands from depth ``at + 2``."""
    return f"a: &x {'[' * height}{']' * height}\nb: {'[' * at}*x{']' * at}\n"


def test_nesting_is_counted_down_each_branch_not_from_the_last_sibling():
    # 30 sequences, a scalar, then its sibling nested 40 deeper: 71 deep on that branch
    text = "[" * 30 + "1, " + "[" * 40 + "]" * 40 + "]" * 30 + "\n"
    with pytest.raises(YamlShapeError) as e:
        check_yaml(text, "f.yaml")
    assert str(e.value) == (
        f"f.yaml: line 1: nested more than {MAX_YAML_DEPTH} deep (the limit, "
        "godobject_drake.config.yaml_guard.MAX_YAML_DEPTH); a scenario nests a few levels: check the "
        "brackets and indentation"
    )


def test_nesting_through_an_alias_is_counted_where_the_alias_puts_it():
    height = 40
    at = MAX_YAML_DEPTH - height - 1  # deepest: (at + 2) + height - 1 = MAX_YAML_DEPTH
    check_yaml(through_alias(height, at), "f.yaml")
    with pytest.raises(YamlShapeError) as e:
        check_yaml(through_alias(height, at + 1), "f.yaml")
    assert str(e.value) == (  # the node named: the alias is that node (line 1), not a copy
        f"f.yaml: line 1: nested more than {MAX_YAML_DEPTH} deep once its aliases are expanded (the limit, "
        "godobject_drake.config.yaml_guard.MAX_YAML_DEPTH); alias a smaller node"
    )


def aliases(n: int, m: int) -> str:
    """``a`` anchors a sequence of ``n`` scalars (n + 1 nodes); ``b`` is a sequence of ``m`` aliases
    of it. Written: the root, two keys, the two sequences and the n scalars (n + 5); each alias
    adds n + 1 once expanded."""
    return "a: &a [" + ", ".join(["1"] * n) + "]\nb: [" + ", ".join(["*a"] * m) + "]\n"


def test_aliases_adding_exactly_the_limit_pass_and_one_more_is_refused_with_the_counts():
    n = 999  # each alias adds 1000 nodes
    check_yaml(aliases(n, MAX_ALIAS_NODES // (n + 1)), "f.yaml")
    m = MAX_ALIAS_NODES // (n + 1) + 1
    with pytest.raises(YamlShapeError) as e:
        check_yaml(aliases(n, m), "f.yaml")
    expanded = n + 5 + m * (n + 1)
    assert str(e.value) == (
        f"f.yaml: its aliases expand to {expanded:.3g} nodes from the {n + 5} written, past the limit "
        f"of {MAX_ALIAS_NODES:,} added (godobject_drake.config.yaml_guard.MAX_ALIAS_NODES): aliases of "
        "aliases multiply; write the values out, or alias less"
    )


def test_aliases_of_an_anchored_mapping_are_counted_too():
    mapping = "{" + ", ".join(f"k{i}: {i}" for i in range(499)) + "}"  # 1 + 2 x 499 = 999 nodes
    text = f"a: &a {mapping}\nb: [" + ", ".join(["*a"] * 101) + "]\n"  # 101 x 999 = 100,899 added
    with pytest.raises(YamlShapeError, match=r"^f\.yaml: its aliases expand to "):
        check_yaml(text, "f.yaml")


def test_an_alias_inside_its_own_node_is_refused_at_its_line():
    with pytest.raises(YamlShapeError) as e:
        check_yaml("z: 0\na: &a [1, *a]\n", "f.yaml")
    assert str(e.value) == (
        "f.yaml: line 2: an alias inside the node its anchor names (a cycle: it expands without end); name "
        "a node outside it"
    )


def test_a_key_twice_is_refused_naming_both_lines_and_only_the_same_key_of_the_same_tag_counts():
    with pytest.raises(YamlShapeError) as e:
        check_yaml("a: 1\nb: 2\na: 3\n", "f\x1b.yaml")
    assert str(e.value).startswith(
        "f\\x1b.yaml: line 3: the key 'a' is given twice in one mapping (first at line 1)"
    )
    check_yaml("1: x\n'1': y\n? [1]\n: p\n? [1]\n: q\n", "f.yaml")  # an int and a str; keys not scalars
    with pytest.raises(YamlShapeError) as e:
        check_yaml("? [1]\n: p\nz: 1\nz: 2\n", "f.yaml")  # after a key that is not a scalar
    assert str(e.value) == (
        "f.yaml: line 4: the key 'z' is given twice in one mapping (first at line 3); a mapping takes each "
        "key once (the loader would keep only the last): remove or rename one"
    )
    with pytest.raises(YamlShapeError, match="line 4: the key 'b'"):
        check_yaml("a: 1\n---\nb: 1\nb: 2\n", "f.yaml")  # in a later document too


def test_text_that_is_not_yaml_is_left_to_the_loader():
    assert check_yaml("a: [1,\n", "f.yaml") is None


def test_a_text_or_file_past_the_size_limit_is_refused_before_it_is_read(tmp_path):
    with pytest.raises(YamlShapeError) as e:
        check_yaml("#" * (MAX_YAML_BYTES + 1), "t")
    assert str(e.value) == (
        "t: 16.0 MiB of YAML, past the 16 MiB limit (godobject_drake.config.yaml_guard.MAX_YAML_BYTES); "
        "write long paths or logs as a CSV log"
    )
    big = tmp_path / "big.yaml"
    with big.open("wb") as f:
        f.truncate(MAX_YAML_BYTES)  # exactly the limit (zero bytes, not YAML: left to the loader)
    check_yaml_file(big, "big.yaml")
    with big.open("ab") as f:
        f.truncate(MAX_YAML_BYTES + 1)
    with pytest.raises(YamlShapeError, match=r"^big\.yaml: 16\.0 MiB of YAML, past the 16 MiB limit"):
        check_yaml_file(big, "big.yaml")
    (tmp_path / "dup.yaml").write_bytes(b"# \xff\xfe not UTF-8: replaced, not an error\na: 1\na: 2\n")
    with pytest.raises(YamlShapeError, match=r"^dup\.yaml: line 3: the key 'a'"):
        check_yaml_file(tmp_path / "dup.yaml", "dup.yaml")


# -- meshes --------------------------------------------------------------------------------------------------

TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


def obj(tmp_path, text: str, name: str = "m.obj"):
    path = tmp_path / name
    path.write_text(text)
    return path


def refused(path) -> str:
    with pytest.raises(MeshFileError) as e:
        check_mesh(path, "M")
    return str(e.value)


def test_an_obj_face_naming_one_vertex_past_the_last_is_refused_with_the_counts(tmp_path):
    check_mesh(obj(tmp_path, TRIANGLE + "f 1 2 3\n"), "M")
    assert refused(obj(tmp_path, TRIANGLE + "f 1 2 4\n")) == (
        "M: line 4: a face names vertex 4, but the mesh has 3 (vertices are numbered 1 to 3, or -1 to -3 "
        "counting back); Drake's reader would read past them (a crash). Fix the mesh: re-export it from the "
        "modelling tool"
    )


def test_forward_references_count_at_the_end_and_the_largest_is_named_at_its_first_line(tmp_path):
    check_mesh(obj(tmp_path, "f 1 2 4\n" + TRIANGLE + "v 1 1 1\n"), "M")  # vertex 4 comes later
    message = refused(obj(tmp_path, TRIANGLE + "f 1 2 5\nf 1 2 9\nf 1 2 9\nf 1 2 6\n"))
    assert message.startswith("M: line 5: a face names vertex 9, but the mesh has 3")


def test_a_face_naming_vertex_1_of_a_file_with_none_is_refused(tmp_path):
    assert refused(obj(tmp_path, "f 1 1 1\n")).startswith(
        "M: line 1: a face names vertex 1, but the mesh has 0"
    )


def test_blank_lines_do_not_end_the_reading(tmp_path):
    assert refused(obj(tmp_path, TRIANGLE + "\n\nf 1 2 -4\n")).startswith(
        "M: line 6: a face names vertex -4,"
    )
    blank = VTK.replace("CELLS", "\nCELLS").replace("4 3 2 1 0", "4 3 2 1 7")
    assert refused(obj(tmp_path, blank, "t.vtk")).startswith("M: line 13: a cell names point 7,")


def test_backward_references_count_what_came_before_and_zero_names_nothing(tmp_path):
    check_mesh(obj(tmp_path, TRIANGLE + "f -1 -2 -3\n"), "M")
    assert refused(obj(tmp_path, TRIANGLE + "f -1 -2 -4\n")).startswith(
        "M: line 4: a face names vertex -4, but the mesh has 3"
    )
    assert refused(obj(tmp_path, "v 0 0 0\nf -1 -1 -1\nv 0 0 1\nf -3 -1 -2\n")).startswith(
        "M: line 4: a face names vertex -3, but the mesh has 2"
    )
    assert refused(obj(tmp_path, TRIANGLE + "f 0 1 2\n")).startswith("M: line 4: a face names vertex 0,")


def test_texture_and_normal_indices_lines_and_points_are_each_checked_against_their_own_count(tmp_path):
    ok = TRIANGLE + "vt 0 0\nvt 1 0\nvn 0 0 1\nf 1/2/1 2/1/1 3//1\nl 1 3\np 2\n"
    check_mesh(obj(tmp_path, ok), "M")
    assert refused(obj(tmp_path, ok + "f 1/3/1 2/1/1 3/1/1\n")).startswith(
        "M: line 10: a face names texture coordinate 3, but the mesh has 2 (texture coordinates are "
        "numbered 1 to 2, or -1 to -2 counting back)"
    )
    assert refused(obj(tmp_path, ok + "f 1//2 2//1 3//1\n")).startswith(
        "M: line 10: a face names normal 2, but the mesh has 1 (normals are numbered 1 to 1"
    )
    assert refused(obj(tmp_path, ok + "l 1 4\n")).startswith("M: line 10: a face names vertex 4,")
    assert refused(obj(tmp_path, ok + "p -4\n")).startswith("M: line 10: a face names vertex -4,")


def test_what_is_not_an_index_is_left_to_drakes_reader(tmp_path):
    check_mesh(obj(tmp_path, TRIANGLE + "\n   \nf a b c\nf 1/x/ 2 3\ng 99\n# f 9 9 9\n"), "M")


def test_only_obj_and_vtk_files_are_read_whatever_their_case(tmp_path):
    check_mesh(tmp_path / "missing.stl", "M")  # not a mesh this checks: not even opened
    assert refused(obj(tmp_path, TRIANGLE + "f 1 2 4\n", name="M.OBJ")).startswith("M: line 4:")


def test_a_mesh_past_the_size_limit_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "big.obj"
    with path.open("wb") as f:
        f.truncate(MAX_MESH_FILE_BYTES)  # exactly the limit: read (zero bytes: no index in it)
    check_mesh(path, "M")
    with path.open("ab") as f:
        f.truncate(MAX_MESH_FILE_BYTES + 1)
    assert refused(path) == (
        "M: 64 MiB, past the 64 MiB limit on a mesh (godobject_drake.config.meshes.MAX_MESH_FILE_BYTES); "
        "decimate the mesh"
    )


VTK = (
    "# vtk DataFile Version 3.0\ntetrahedra\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 double\n"
    "0 0 0\n1 0 0\n0 1 0\n0 0 1\nCELLS 2 10\n4 0 1 2 3\n4 3 2 1 0\nCELL_TYPES 2\n10\n10\n"
)


def test_a_vtk_cell_naming_a_point_past_the_last_or_below_zero_is_refused_at_its_line(tmp_path):
    check_mesh(obj(tmp_path, VTK, "t.vtk"), "M")
    assert refused(obj(tmp_path, VTK.replace("4 3 2 1 0", "4 3 2 1 4"), "t.vtk")) == (
        "M: line 12: a cell names point 4, but the mesh has 4 (numbered 0 to 3); Drake's reader would read "
        "past them. Fix the mesh: write it from its tetrahedra"
    )
    assert refused(obj(tmp_path, VTK.replace("4 0 1 2 3", "4 0 1 -1 3"), "t.vtk")).startswith(
        "M: line 11: a cell names point -1,"
    )


def test_a_vtk_cells_first_point_and_the_points_own_coordinates(tmp_path):
    assert refused(obj(tmp_path, VTK.replace("4 3 2 1 0", "4 9 2 1 0"), "t.vtk")).startswith(
        "M: line 12: a cell names point 9,"
    )
    # integer coordinates past the point count, before the cells: coordinates, not indices
    check_mesh(obj(tmp_path, VTK.replace("0 0 0\n1 0 0\n0 1 0", "7 9 9\n1 8 8\n0 1 5"), "t.vtk"), "M")


def test_a_malformed_vtk_header_line_is_left_to_drake(tmp_path):
    check_mesh(obj(tmp_path, VTK.replace("POINTS 4 double", "POINTS"), "t.vtk"), "M")  # no count: no check
    check_mesh(obj(tmp_path, VTK.replace("CELLS 2 10", "CELLS 2"), "t.vtk"), "M")
    untyped = VTK.replace("POINTS 4 double", "POINTS 4").replace("4 3 2 1 0", "4 3 2 1 4")
    assert refused(obj(tmp_path, untyped, "t.vtk")).startswith("M: line 12: a cell names point 4,")
    check_mesh(obj(tmp_path, VTK.replace("4 3 2 1 0", "4 3 2 1 X4"), "t.vtk"), "M")  # not a number


def test_a_vtk_cells_count_is_not_an_index_and_other_sections_are_not_cells(tmp_path):
    # a cell of 4 points says "4" first (here point 4 does not exist); cell types 10 and point data
    # past the last point are not indices; a CELLS section's length ends it
    tail = "POINT_DATA 4\nSCALARS s int 1\nLOOKUP_TABLE default\n7 8 9 10\n"
    check_mesh(obj(tmp_path, VTK + tail, "t.vtk"), "M")
    after = VTK.replace("CELL_TYPES 2\n10\n10\n", "12 13\n")  # past the section's 10 numbers
    check_mesh(obj(tmp_path, after, "t.vtk"), "M")
    # a section that ends exactly (a cell of no point last), then a field of numbers
    exact = VTK.replace("CELLS 2 10\n4 0 1 2 3\n4 3 2 1 0\nCELL_TYPES 2\n10\n10\n", "CELLS 2 4\n2 0 1\n0\n")
    check_mesh(obj(tmp_path, exact + "FIELD FieldData 1\nf 3 1 int\n7 7 7\n", "t.vtk"), "M")


def test_a_vtk_51_connectivity_is_checked_and_its_offsets_are_not(tmp_path):
    head = "# vtk DataFile Version 5.1\nt\nASCII\nDATASET UNSTRUCTURED_GRID\n"
    head += "POINTS 4 float\n0 0 0 1 0 0 0 1 0 0 0 1\n"
    good = head + "CELLS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n0 1 2 3\n"
    good += "CELL_TYPES 1\n10\n"
    check_mesh(obj(tmp_path, good, "t.vtk"), "M")
    bad = good.replace("0 1 2 3\nCELL", "0 1 2 5\nCELL")
    assert refused(obj(tmp_path, bad, "t.vtk")).startswith("M: line 11: a cell names point 5, but the mesh")


def test_a_vtk_51_connectivity_of_one_index_a_line_is_checked_to_its_end(tmp_path):
    head = "# vtk DataFile Version 5.1\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n"
    cells = (
        head + "0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n"
    )
    assert refused(obj(tmp_path, cells + "0\n1\n2\n5\n", "t.vtk")).startswith(
        "M: line 14: a cell names point 5,"
    )


def test_a_vtk_51_connectivity_line_is_all_indices_and_the_data_sections_end_it(tmp_path):
    head = "# vtk DataFile Version 5.1\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n"
    cells = (
        head + "0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n"
    )
    assert refused(obj(tmp_path, cells + "5 1 2 3\n", "t.vtk")).startswith(
        "M: line 11: a cell names point 5,"
    )
    for section in ("CELL_DATA 1", "POINT_DATA 4"):
        check_mesh(obj(tmp_path, cells + f"0 1 2 3\n{section}\nSCALARS s int 1\n7 8 9 10\n", "t.vtk"), "M")


def test_binary_or_foreign_vtk_files_are_left_to_drake(tmp_path):
    bad = VTK.replace("4 3 2 1 0", "4 3 2 1 9")
    check_mesh(obj(tmp_path, bad.replace("ASCII", "BINARY"), "t.vtk"), "M")
    check_mesh(obj(tmp_path, bad.replace("# vtk", "# not vtk"), "t.vtk"), "M")


# -- keys ----------------------------------------------------------------------------------------------------


def test_a_key_given_where_its_files_path_goes_is_refused_naming_its_length(monkeypatch, tmp_path):
    key = "0123456789abcdef" * 2  # 32 hex digits: the shortest refused
    with pytest.raises(KeyFileError) as e:
        key_path(key)
    assert str(e.value) == (
        "the key file holds 32 hex digits, a key itself rather than the path of a key file (it would be "
        "taken as a file name, and a new key made there): put the key in a file (mode 0600) and give that "
        "file's path"
    )
    assert key_path(key[:-1]) == __import__("pathlib").Path(key[:-1])  # 31: a name like any other
    monkeypatch.setenv(KEY_ENV, f"  {key * 2}\n")
    with pytest.raises(KeyFileError, match=rf"^\${KEY_ENV} holds 64 hex digits, a key itself"):
        key_path()
    monkeypatch.setenv(KEY_ENV, str(tmp_path / "k"))
    assert key_path() == tmp_path / "k"


def test_a_missing_named_key_file_names_the_default_instead(monkeypatch, tmp_path):
    monkeypatch.setenv(KEY_ENV, str(tmp_path / "default.key"))
    with pytest.raises(KeyFileError) as e:
        load_key(tmp_path / "typo.key")
    assert str(e.value).startswith(f"key file {tmp_path / 'typo.key'} does not exist: give the key file")
    assert f"to use the default ({tmp_path / 'default.key'}), made on first use" in str(e.value)
    assert not (tmp_path / "typo.key").exists() and not (tmp_path / "default.key").exists()
    monkeypatch.setenv(KEY_ENV, "ab" * 16)  # the default itself is refused: named by its rule
    with pytest.raises(KeyFileError, match=rf"default \(\${KEY_ENV}, else ~/\.config/godobject/link\.key\)"):
        load_key(tmp_path / "typo.key")


# -- the driver's outputs ------------------------------------------------------------------------------------


def test_a_log_is_a_regular_file_opened_empty_and_anything_else_is_refused_naming_the_fix(tmp_path):
    log = tmp_path / "d.csv"
    log.write_text("an older run\n")
    with open_log_file(str(log)) as f:
        assert os.get_blocking(f.fileno()) and fcntl.fcntl(f.fileno(), fcntl.F_GETFD) & fcntl.FD_CLOEXEC
        f.write("t\n")
    assert log.read_text() == "t\n"
    umask = os.umask(0o022)
    try:
        open_log_file(str(tmp_path / "new.csv")).close()
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o644  # 0o666 less the umask
    long = tmp_path / ("x" * 300)
    with pytest.raises(BadInput) as e:
        open_log_file(str(long))
    assert str(e.value) == f"--log {long}: File name too long; give a regular file you can write"
    with pytest.raises(BadInput) as e:
        open_log_file(str(tmp_path))
    assert str(e.value) == f"--log: {tmp_path} is a folder; give a file name, e.g. {tmp_path / 'driver.csv'}"
    with pytest.raises(BadInput, match=r"^--log: .*the folder .*nowhere does not exist"):
        open_log_file(str(tmp_path / "nowhere" / "d.csv"))
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for stream in (fifo, "/dev/null"):
        with pytest.raises(BadInput) as e:
            open_log_file(str(stream))
        assert str(e.value) == (
            f"--log {stream} is not a regular file (a FIFO, a pipe or a device): the device's loop writes to "
            "it every period and must never wait on a reader; give a file, e.g. driver.csv"
        )


def test_a_summary_naming_a_folder_or_a_missing_one_is_refused_and_a_file_passes(tmp_path):
    check_summary(str(tmp_path / "s.json"))
    assert not (tmp_path / "s.json").exists()  # checked, not made
    with pytest.raises(BadInput) as e:
        check_summary(str(tmp_path))
    assert (
        str(e.value)
        == f"--summary: {tmp_path} is a folder; give a file name, e.g. {tmp_path / 'driver.json'}"
    )
    with pytest.raises(BadInput, match=r"^--summary: .*does not exist"):
        check_summary(str(tmp_path / "nowhere" / "s.json"))


def test_a_log_that_can_no_longer_grow_stops_the_driver_once_and_keeps_the_row(tmp_path):
    from godobject_drake.driver.families import RATED, EmulatedDevice, HandPath
    from godobject_drake.link.transport import driver_lcm

    still = HandPath(np.zeros(1), np.zeros((1, 3)), np.ones(1, bool), np.zeros(1, bool))
    link = driver_lcm("udp://127.0.0.1:9")
    try:
        d = Driver(EmulatedDevice(still), link, RATED["emulated"], rate_hz=1000.0, watchdog_periods=10,
                   max_force_n=12.0)  # fmt: skip
        d.log_path, d.log_file = tmp_path / "d.csv", open(tmp_path / "d.csv", "w")
        d._row((0.5, 1, "ok", 1.234567890123))
        d.log_file.close()
        assert (tmp_path / "d.csv").read_text() == "0.5,1,ok,1.23456789\n"  # floats to 9 digits
        d.log_path, d.log_file = "/dev/full", open("/dev/full", "w", buffering=1)
        d._row((0.5, 1, "ok"))
        assert d.output_error == (
            "--log /dev/full: could not write (No space left on device); the force was zeroed and the driver "
            "stopped. Free space on that disk, or give --log another place"
        )
        assert d.stop_requested and d.log_file is None and list(d.rows)[-1] == (0.5, 1, "ok")
        d._row((0.6, 2, "ok"))  # in memory from now on
        assert list(d.rows)[-2:] == [(0.5, 1, "ok"), (0.6, 2, "ok")]
        d.log_file = open("/dev/full", "w", buffering=1)
        d._row((0.7, 3, "ok"))
        assert d.output_error.startswith("--log /dev/full: could not write")  # the first cause kept
    finally:
        link.close()
