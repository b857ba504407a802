"""Making a third-party URDF parseable by Drake, offline: meshes, mimic tags, transmissions.

What Drake 1.51 does with a URDF's meshes (tried on the Unitree G1 and PAL
TALOS models of ``example-robot-data``, whose meshes are all STL):

* a ``<collision>`` mesh that is not ``.obj``, ``.vtk`` or ``.gltf`` stops the
  parse: Drake computes the convex hull of every proximity mesh and its
  ``MakeConvexHull`` refuses other extensions ("MakeConvexHull only applies to
  .obj, .vtk, and .gltf meshes; unsupported extension '.stl'");
* a ``<visual>`` STL mesh is accepted, but Meshcat does not show it ("Drake's
  Meshcat only supports Mesh/Convex specifications which use .obj, .gltf, or
  .dae files") and the VTK render engines read only ``.obj`` and ``.gltf``.

So :func:`prepare_urdf` rewrites the URDF text before parsing:

* every visual mesh of another kind is converted once to OBJ with ``trimesh``
  (the ``robots`` extra), cached under :func:`cache_dir` by the source file's
  content hash; a mesh that cannot be read or converted is replaced by the
  link's primitive collision shapes, with a warning naming the mesh;
* collision elements are dropped unless asked for (then meshes are converted
  like the visuals): the stop stack's contact is the soles', added at the sole
  rectangles by :func:`drake_estop.robots.plant.add_robot`;
* mesh references become absolute ``file://`` URIs (``package://`` resolved through the
  description's ``PackageMap``), so the text parses with no package map;
* ``<mimic>`` on a fixed joint is dropped (Drake refuses "Joint ... which has 0
  DOF cannot mimic joint ..."; TALOS's reduced model has them on its welded
  fingers), as are ``<transmission>`` elements of a type other than
  ``SimpleTransmission`` (Drake ignores them with a warning) and joint
  ``friction`` attributes (Drake does not model joint friction and warns).

The joints' ``<limit effort>`` values are collected on the way: Drake keeps a
joint's effort limit only on an actuator made from a transmission, and
:func:`~drake_estop.robots.plant.add_robot` adds the actuators a model lacks.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

from drake_estop.robots.loading import resolve_uri

LOGGER = logging.getLogger("drake_estop.robots")

#: Mesh kinds Drake 1.51 can use as visuals (Meshcat and the VTK render engines) and for proximity.
DRAKE_MESHES = (".obj", ".gltf")
#: The XML namespaces a URDF may use, registered so the rewritten text keeps their prefixes.
NAMESPACES = {"drake": "http://drake.mit.edu", "xacro": "http://ros.org/wiki/xacro"}
PRIMITIVES = ("box", "cylinder", "sphere", "capsule", "drake:capsule", "drake:ellipsoid")

for _prefix, _uri in NAMESPACES.items():
    ElementTree.register_namespace(_prefix, _uri)


def cache_dir() -> Path:
    """Where converted meshes are kept: ``$DRAKE_ESTOP_CACHE``, else ``$XDG_CACHE_HOME/drake_estop``, else
    ``~/.cache/drake_estop``."""
    if os.environ.get("DRAKE_ESTOP_CACHE"):
        return Path(os.environ["DRAKE_ESTOP_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "drake_estop"


@dataclass
class PreparedUrdf:
    """A URDF rewritten for Drake (see the module docstring).

    Attributes
    ----------
    text : str
        The URDF, parseable with ``Parser.AddModelsFromString(text, "urdf")``.
    efforts : dict
        Joint name -> ``<limit effort>`` [N m] of every joint that gives one.
    fallbacks : list of str
        The meshes replaced by collision shapes.
    """

    text: str
    efforts: dict = field(default_factory=dict)
    fallbacks: list = field(default_factory=list)


def convert_mesh(source: Path) -> Path:
    """``source`` as an OBJ file in the cache (converted once, by content hash).

    Raises
    ------
    ImportError
        Without ``trimesh`` (the ``robots`` extra).
    ValueError
        When the file cannot be read as a triangle mesh.
    """
    digest = hashlib.sha256(source.read_bytes()).hexdigest()[:16]
    target = cache_dir() / "meshes" / f"{source.stem}-{digest}.obj"
    if target.is_file():
        return target
    import trimesh  # the robots extra

    try:
        mesh = trimesh.load(str(source), force="mesh")
    except Exception as error:  # trimesh raises many kinds
        raise ValueError(f"trimesh cannot read {source}: {error}") from error
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{source} holds no triangles")
    target.parent.mkdir(parents=True, exist_ok=True)
    text = trimesh.exchange.obj.export_obj(mesh, include_color=False, include_texture=False)
    with tempfile.NamedTemporaryFile("w", dir=target.parent, suffix=".tmp", delete=False) as handle:
        handle.write(text)
    os.replace(handle.name, target)
    return target


def _usable_mesh(mesh, *, packages, folder: Path) -> None:
    """Point ``mesh``'s filename at a file Drake reads (converting it if needed); raise ValueError if none."""
    source = resolve_uri(mesh.get("filename", ""), packages, relative_to=folder)
    if not source.is_file():
        raise ValueError(f"mesh file {source} does not exist")
    if source.suffix.lower() not in DRAKE_MESHES:
        try:
            source = convert_mesh(source)
        except ImportError as error:
            raise ValueError(f"converting {source} needs trimesh: pip install -e '.[robots]'") from error
    mesh.set("filename", source.resolve().as_uri())  # a string parse takes no bare path


def _geometry_kind(element) -> str | None:
    geometry = element.find("geometry")
    if geometry is None or len(geometry) == 0:
        return None
    return geometry[0].tag


def _collision_as_visual(collision, *, packages, folder: Path):
    """A ``<visual>`` copy of ``collision``, or None when its shape cannot be shown."""
    visual = ElementTree.fromstring(ElementTree.tostring(collision))
    visual.tag = "visual"
    visual.attrib.pop("name", None)
    for child in list(visual):
        if child.tag not in ("origin", "geometry"):
            visual.remove(child)
    if _geometry_kind(visual) == "mesh":
        try:
            _usable_mesh(visual.find("geometry/mesh"), packages=packages, folder=folder)
        except ValueError:
            return None
    return visual if _geometry_kind(visual) is not None else None


def _prepare_visuals(link, *, packages, folder: Path, fallbacks: list) -> None:
    """Convert the link's visual meshes; replace one that fails by the link's collision shapes."""
    for visual in link.findall("visual"):
        mesh = visual.find("geometry/mesh")
        if mesh is None:
            continue
        name = mesh.get("filename", "")
        try:
            _usable_mesh(mesh, packages=packages, folder=folder)
        except ValueError as error:
            link.remove(visual)
            stand_ins = [v for c in link.findall("collision")
                         if (v := _collision_as_visual(c, packages=packages, folder=folder)) is not None]
            for stand_in in stand_ins:
                link.append(stand_in)
            fallbacks.append(name)
            LOGGER.warning("link %r: visual mesh %s cannot be used (%s); showing %d collision shape(s) instead",
                           link.get("name"), name, error, len(stand_ins))


def _prepare_collisions(link, *, keep: bool, packages, folder: Path) -> None:
    """Drop the link's collisions, or (``keep``) convert their meshes, dropping those that fail."""
    for collision in link.findall("collision"):
        mesh = collision.find("geometry/mesh")
        if not keep:
            link.remove(collision)
        elif mesh is not None:
            try:
                _usable_mesh(mesh, packages=packages, folder=folder)
            except ValueError as error:
                link.remove(collision)
                LOGGER.warning("link %r: collision mesh %s dropped (%s)", link.get("name"), mesh.get("filename"),
                               error)


def _prepare_joints(root) -> dict:
    """Drop what Drake refuses or warns about on joints; return joint -> effort limit [N m]."""
    efforts = {}
    for joint in root.findall("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("effort") is not None:
            efforts[joint.get("name")] = float(limit.get("effort"))
        if joint.get("type") == "fixed":
            for mimic in joint.findall("mimic"):
                joint.remove(mimic)
        for dynamics in joint.findall("dynamics"):
            dynamics.attrib.pop("friction", None)
    for transmission in root.findall("transmission"):
        kind = transmission.get("type") or transmission.findtext("type") or ""
        if not kind.endswith("SimpleTransmission"):
            root.remove(transmission)
    return efforts


def prepare_urdf(path: Path, *, packages, visuals: bool = True, collisions: bool = False) -> PreparedUrdf:
    """The URDF at ``path`` rewritten for Drake (see the module docstring).

    Parameters
    ----------
    path : pathlib.Path
        The URDF file.
    packages : pydrake.multibody.parsing.PackageMap
        Resolves the ``package://`` URIs of its meshes.
    visuals : bool, optional
        Keep (and convert) the visual geometry; False drops it (a plant without a scene graph).
    collisions : bool, optional
        Keep (and convert) the model's collision geometry (default: drop it).

    Returns
    -------
    PreparedUrdf
    """
    root = ElementTree.parse(path).getroot()
    folder = path.parent
    fallbacks = []
    for link in root.findall("link"):
        if visuals:
            _prepare_visuals(link, packages=packages, folder=folder, fallbacks=fallbacks)
        else:
            for visual in link.findall("visual"):
                link.remove(visual)
        _prepare_collisions(link, keep=collisions and visuals, packages=packages, folder=folder)
    efforts = _prepare_joints(root)
    return PreparedUrdf(text=ElementTree.tostring(root, encoding="unicode"), efforts=efforts, fallbacks=fallbacks)


def mesh_sole_extents(path: Path, *, band: float = 0.001) -> dict:
    """The bottom face of a foot mesh: extents of its vertices within ``band`` of its lowest point.

    A help for writing a description's sole rectangle (the built-in ``g1`` and ``talos`` numbers
    were checked with it).

    Parameters
    ----------
    path : pathlib.Path
        A mesh file ``trimesh`` reads (STL, OBJ, ...), in the foot body's frame [m].
    band : float, optional
        Height above the lowest vertex that counts as the sole [m].

    Returns
    -------
    dict
        ``bottom`` (z of the lowest vertex), ``x`` and ``y`` ((min, max) of the band's vertices) [m].
    """
    import trimesh  # the robots extra

    vertices = trimesh.load(str(path), force="mesh").vertices
    bottom = float(vertices[:, 2].min())
    sole = vertices[vertices[:, 2] <= bottom + band]
    return {"bottom": bottom, "x": (float(sole[:, 0].min()), float(sole[:, 0].max())),
            "y": (float(sole[:, 1].min()), float(sole[:, 1].max()))}
