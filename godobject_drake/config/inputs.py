"""Every file a scenario names, checked before anything reads it.

Drake's parser opens whatever a directive names and reads it whole: a FIFO hung the run until it
was killed, a 2 GB file was read into memory (2.26 GB) before Drake called it empty, a symlink loop
ended in a ``RuntimeError`` traceback. :func:`check_inputs` walks what a scenario will make Drake
and the device read (the directives' ``file:`` of ``add_model`` and ``add_directives``, the
directives those files add in turn, the files a model includes or meshes it names, each device's
``path`` and ``log``) and refuses, naming the file and where the scenario names it, one that is
not a regular file (a FIFO, a device, a socket), past :data:`MAX_INPUT_FILE_BYTES`, or a symlink
loop; a mesh whose indices reach past its vertices (:mod:`godobject_drake.config.meshes`); a
directives file past the YAML bounds (:mod:`godobject_drake.config.yaml_guard`). A file that
does not exist is left to the reader that says so today (Drake, the device).

What the check cannot close: a file swapped for a FIFO between the check and Drake's read (a
race only someone who can write the scene's folder can run), and a model file Drake reaches by a
path this walk does not know (a ``model://`` URI, an MJCF ``<include>``).
"""

import errno
import os
import re
import stat
from pathlib import Path

import yaml

from godobject_drake.config.meshes import MeshFileError, check_mesh
from godobject_drake.config.yaml_guard import YamlShapeError, check_yaml_file, shown

# A model, mesh, directives or device file larger than this is refused before anything reads it:
# the shipped scenes' largest is 0.02 MB, and a mesh this size is far past what a real-time scene
# can draw and collide. Past it: decimate the mesh or split the model.
MAX_INPUT_FILE_BYTES = 256 * 2**20

MODEL_SUFFIXES = (".sdf", ".urdf", ".xml")  # parsed for the files they include and the meshes they name
DIRECTIVES_SUFFIX = ".dmd.yaml"


class InputFileError(ValueError):
    """A scenario's input file that must not be read: names the file, where it is named, why, and the fix."""


def _kind(mode: int) -> str:
    """What a file that is not a regular one is, and what reading it would do."""
    for test, name in (
        (
            stat.S_ISFIFO,
            "a FIFO (named pipe), not a regular file: reading it waits for a writer, forever if none comes",
        ),
        (stat.S_ISCHR, "a character device, not a regular file: reading /dev/zero, say, never ends"),
        (stat.S_ISBLK, "a block device, not a regular file"),
        (stat.S_ISSOCK, "a socket, not a regular file"),
        (stat.S_ISDIR, "a folder, not a file"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_input_file(path: str | Path, where: str, *, size_limit: bool = True) -> bool:
    """Refuse ``path`` (:class:`InputFileError`, naming ``where``) if it is a symlink loop, not a
    regular file, or (``size_limit``) past :data:`MAX_INPUT_FILE_BYTES`. Returns False when
    nothing is there (its reader says so), True for a file that may be read."""
    name, where = shown(path), shown(where)  # a control character in a name is escaped, not printed
    try:
        st = os.stat(path)  # follows links, as a reader would
    except FileNotFoundError:
        return False
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise InputFileError(
                f"{where}: {name}: a symlink loop (the link points back at itself through other "
                "links); point it at the file"
            ) from None
        raise InputFileError(f"{where}: {name}: cannot be read: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{where}: {name} is {_kind(st.st_mode)}; give the model or data file itself")
    if size_limit and st.st_size > MAX_INPUT_FILE_BYTES:
        raise InputFileError(
            f"{where}: {name} is {st.st_size / 2**20:.0f} MiB, past the {MAX_INPUT_FILE_BYTES // 2**20} MiB "
            "limit on a model, mesh or directives file (it would be read whole into memory); decimate the "
            "mesh or split the model (godobject_drake.config.inputs.MAX_INPUT_FILE_BYTES)"
        )
    return True


class _Resolver:
    """Drake's package map for ``package://`` URIs (the project's models, Drake's own); a package it
    would download (``drake_models``) or does not know is left to Drake."""

    def __init__(self, models_dir: Path):
        from pydrake.multibody.parsing import PackageMap

        try:
            self.map = PackageMap()
        except RuntimeError:  # drake_models not downloadable (no network): Drake's parse says so, better
            self.map = PackageMap.MakeEmpty()
        xml = models_dir / "package.xml"
        if xml.is_file():
            self.map.AddPackageXml(str(xml))

    def path(self, uri: str, base: Path | None) -> Path | None:
        """The file ``uri`` names, or None where it cannot be told without Drake."""
        if uri.startswith("package://"):
            package, _, rest = uri[len("package://") :].partition("/")
            if package == "drake_models" or not self.map.Contains(package):
                return None
            return Path(self.map.GetPath(package)) / rest
        if uri.startswith("file://"):  # as written: urlparse drops a newline, cuts at a # or a ?
            return Path(uri[len("file://") :])
        if "://" in uri or not uri:
            return None
        return Path(uri) if Path(uri).is_absolute() or base is None else base / uri


class _Walk:
    def __init__(self, models_dir: Path):
        self.resolve = _Resolver(models_dir)
        self.seen: set[str] = set()

    def file(self, uri: str, where: str, base: Path | None) -> None:
        path = self.resolve.path(uri, base)
        if path is None:
            return
        key = os.path.abspath(path)
        if key in self.seen:
            return
        self.seen.add(key)
        if not check_input_file(path, where):
            return
        name = path.name.lower()
        try:  # a mesh whose indices reach past its vertices crashed Drake's reader (config.meshes)
            check_mesh(path, f"{shown(where)}: {shown(path)}")
        except MeshFileError as e:
            raise InputFileError(str(e)) from None
        if name.endswith(DIRECTIVES_SUFFIX):
            self.directives_file(path, where)
        elif name.endswith(MODEL_SUFFIXES):
            self.model_file(path, where)

    def directives(self, directives, where: str, base: Path | None) -> None:
        for i, d in enumerate(directives):
            if d.add_model is not None:
                self.file(d.add_model.file, f"{where}[{i}].add_model.file", base)
            if d.add_directives is not None:
                self.file(d.add_directives.file, f"{where}[{i}].add_directives.file", base)

    def directives_file(self, path: Path, where: str) -> None:
        try:  # Drake's parser expands its aliases: a bomb, a deep nest, a key twice, before it reads it
            check_yaml_file(path, f"{where}: {path}")
        except YamlShapeError as e:
            raise InputFileError(str(e)) from None
        text = path.read_text(errors="replace")
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError:
            return  # not YAML: Drake's parser names the error
        items = data.get("directives") if isinstance(data, dict) else None
        for i, d in enumerate(items if isinstance(items, list) else []):
            for key in ("add_model", "add_directives"):
                uri = (
                    d.get(key, {}).get("file")
                    if isinstance(d, dict) and isinstance(d.get(key), dict)
                    else None
                )
                if isinstance(uri, str):
                    self.file(uri, f"{where} → {path.name}: directives[{i}].{key}.file", path.parent)

    def model_file(self, path: Path, where: str) -> None:
        # Read as text, not parsed: Drake's SDFormat takes a drake: prefix it never declares, which an
        # XML parser refuses (an unbound prefix).
        text = path.read_text(errors="replace")
        for found in URI.finditer(text):
            uri = (found.group("uri") or found.group("attribute")).strip()
            tag = "<uri>" if found.group("uri") is not None else f"{found.group('name')}="
            self.file(uri, f"{where} → {path.name}: {tag} {uri}", path.parent)


# SDFormat's <include><uri> and <mesh><uri>, URDF's <mesh filename="...">, MJCF's <mesh file="...">.
URI = re.compile(
    r"<uri>(?P<uri>[^<]*)</uri>|\b(?P<name>filename|file)\s*=\s*[\"'](?P<attribute>[^\"']*)[\"']"
)


def check_inputs(scenario, models_dir: Path, where: str = "scenario") -> None:
    """Check every file ``scenario`` names (module docstring) before anything reads it; raises
    :class:`InputFileError`. Its paths are absolute already (``resolve_paths``)."""
    walk = _Walk(models_dir)
    walk.directives(scenario.directives, f"{where}: directives", None)
    for name, body in getattr(scenario, "deformables", {}).items():
        if body.mesh:
            walk.file(body.mesh, f"{where}: deformables.{name}.mesh", None)
    holders = scenario.tools or {"": scenario}  # each tool's device: its own, or the scenario's
    for name, holder in holders.items():
        at = f"tools.{name}." if name else ""
        for attribute in ("path", "log"):
            value = getattr(holder.device, attribute, "")
            if isinstance(value, str) and value and "://" not in value:
                # a log is read a row at a time, up to where the run reaches: no size limit
                check_input_file(value, f"{where}: {at}device.{attribute}", size_limit=attribute == "path")
