"""Robot descriptions from YAML; model files and ``package://`` URIs.

:func:`read_description` reads a :class:`~drake_estop.robots.description.RobotDescription`
from a YAML file (:func:`built_in_path`: a built-in name's, :data:`BUILT_IN`)
with Drake's ``yaml_load_typed``; :func:`drake_estop.robots.parameters.load_robot`
also checks it against its model. A description file names
only what differs from the defaults of the classes, e.g.::

    name: my_robot
    model: urdf/my_robot.urdf        # relative to this file's folder
    floating_base: pelvis
    torso_body: torso
    left_foot: {body: l_foot, translation: [0, 0, -0.05], toe: 0.12, heel: 0.08, inner: 0.05, outer: 0.06}
    ...

The description classes are frozen and hold tuples, which ``yaml_load_typed``
cannot fill; :func:`yaml_schema` makes a mutable twin of each (tuples read as
lists, every field defaulting to None so that a missing key keeps the class's
default) and :func:`_from_schema` converts back, naming the field of any value
the classes reject.

``package://NAME/...`` URIs (the model's and its meshes') resolve through a
Drake ``PackageMap`` (:func:`package_map`) holding the description's packages
and ``drake_estop_models``, the folder of the project's own humanoid.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import typing
import xml.etree.ElementTree as ElementTree
from importlib import resources
from pathlib import Path

from pydrake.common.yaml import yaml_load_typed
from pydrake.multibody.parsing import PackageMap

from drake_estop.model import MODEL_PATH
from drake_estop.robots.description import (
    Foot,
    JointAngle,
    LegJoints,
    LimitOverride,
    PackagePath,
    RobotDescription,
    ServoGain,
    SwingJoint,
)

#: The robots shipped with the package: name -> description file in this folder.
BUILT_IN = {"default": "default.yaml", "g1": "g1.yaml", "talos": "talos.yaml"}
#: The package name under which ``package://`` finds the project's own models folder.
MODELS_PACKAGE = "drake_estop_models"
#: Model file kinds Drake's parser reads.
MODEL_SUFFIXES = (".urdf", ".sdf", ".xml")

_CLASSES = (Foot, JointAngle, LegJoints, LimitOverride, PackagePath, ServoGain, SwingJoint, RobotDescription)


class MissingRobotPackage(ValueError):
    """A description's package comes from a Python distribution that is not installed."""


# -- schema twins ---------------------------------------------------------------------------------


def _twin_type(hint):
    """The type ``yaml_load_typed`` reads in place of ``hint``."""
    if dataclasses.is_dataclass(hint):
        return yaml_schema(hint)
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is tuple:
        return list[_twin_type(args[0])]
    if args and type(None) in args:  # X | None
        inner = [a for a in args if a is not type(None)]
        return _twin_type(inner[0]) | None
    return hint


@functools.cache
def yaml_schema(cls):
    """A mutable dataclass that ``yaml_load_typed`` fills in place of the frozen ``cls``."""
    hints = typing.get_type_hints(cls)
    fields = [(f.name, _twin_type(hints[f.name]) | None, dataclasses.field(default=None))
              for f in dataclasses.fields(cls)]
    return dataclasses.make_dataclass(f"{cls.__name__}Schema", fields)


_ORIGINAL = {}


def _original(twin):
    if not _ORIGINAL:
        _ORIGINAL.update({yaml_schema(cls): cls for cls in _CLASSES})
    return _ORIGINAL.get(twin)


def _convert(value, where: str):
    """A twin (or a list of them) back to the real classes; ``where`` names the field."""
    if isinstance(value, list):
        return tuple(_convert(item, f"{where}[{i}]") for i, item in enumerate(value))
    cls = _original(type(value))
    if cls is None:
        return value
    kwargs = {f.name: _convert(getattr(value, f.name), f"{where}.{f.name}".lstrip("."))
              for f in dataclasses.fields(cls) if getattr(value, f.name) is not None}
    try:
        return cls(**kwargs)
    except ValueError as error:
        raise ValueError(f"{where}: {error}" if where else str(error)) from error


def _from_schema(value) -> RobotDescription:
    return _convert(value, "")


# -- loading --------------------------------------------------------------------------------------


def built_in_path(name: str) -> Path:
    """The description file of the built-in robot ``name`` (a key of :data:`BUILT_IN`)."""
    if name not in BUILT_IN:
        raise ValueError(f"unknown robot name {name!r}: the built-in robots are {', '.join(BUILT_IN)}, "
                         "or give the path of a description YAML file")
    return Path(str(resources.files("drake_estop.robots") / BUILT_IN[name]))


def read_description(*, filename: str | Path | None = None, text: str | None = None,
                     folder: str | Path | None = None) -> RobotDescription:
    """A description from a YAML file or string (exactly one), not checked against its model.

    Parameters
    ----------
    filename : str or pathlib.Path, optional
        The description file.
    text : str, optional
        The same, as a string.
    folder : str or pathlib.Path, optional
        What relative paths in ``text`` are relative to (default: the current folder; for a file,
        the file's folder).

    Returns
    -------
    RobotDescription
        With relative model and package paths made absolute.

    Raises
    ------
    ValueError
        Naming the key or the field whose value is wrong, or the file that cannot be read.
    """
    if (filename is None) == (text is None):
        raise ValueError("read_description needs exactly one of filename= or text=")
    source = f"robot description {filename}" if filename is not None else "robot description text"
    if filename is not None:
        if not Path(filename).is_file():
            raise ValueError(f"{source}: no such file")
        folder = Path(filename).resolve().parent
    try:
        schema = yaml_load_typed(schema=yaml_schema(RobotDescription), data=text,
                                 filename=None if filename is None else str(filename))
        description = _from_schema(schema)
    except (RuntimeError, TypeError, ValueError, KeyError) as error:
        raise ValueError(f"{source}: {error}") from error
    return _absolute_paths(description, Path(folder or Path.cwd()).resolve())


def _absolute_paths(description: RobotDescription, folder: Path) -> RobotDescription:
    """``description`` with its relative model path and package paths made relative to ``folder``."""
    model = description.model
    if "://" not in model and not Path(model).is_absolute():
        model = str(folder / model)
    packages = tuple(dataclasses.replace(p, path=str(folder / p.path))
                     if p.path is not None and not Path(p.path).is_absolute() else p
                     for p in description.packages)
    return dataclasses.replace(description, model=model, packages=packages)


# -- packages and the model file -----------------------------------------------------------------


def package_folder(package: PackagePath, *, robot: str = "") -> Path:
    """The folder of ``package`` (see :class:`~drake_estop.robots.description.PackagePath`)."""
    if package.path is not None:
        folder = Path(package.path)
    else:
        try:
            distribution = importlib.metadata.distribution(package.distribution)
        except importlib.metadata.PackageNotFoundError as error:
            extra = f"pip install -e '.[{package.extra}]'" if package.extra else f"pip install {package.distribution}"
            raise MissingRobotPackage(
                f"robot {robot!r} needs the Python package {package.distribution!r} for package "
                f"{package.name!r} (packages): install it with {extra}") from error
        folder = Path(str(distribution.locate_file(package.subdirectory)))
    if not folder.is_dir():
        raise ValueError(f"packages: the folder of package {package.name!r} does not exist: {folder}")
    return folder.resolve()


def package_map(description: RobotDescription) -> PackageMap:
    """A Drake ``PackageMap`` with the description's packages and :data:`MODELS_PACKAGE` (nothing remote)."""
    packages = PackageMap.MakeEmpty()
    packages.Add(MODELS_PACKAGE, str(MODEL_PATH.parent))
    for package in description.packages:
        packages.Add(package.name, str(package_folder(package, robot=description.name)))
    return packages


def resolve_uri(uri: str, packages: PackageMap, *, relative_to: Path) -> Path:
    """The file of a model or mesh reference: ``package://``, ``file://``, absolute or relative."""
    if uri.startswith("package://"):
        name = uri[len("package://"):].split("/", 1)[0]
        if not packages.Contains(name):
            raise ValueError(f"package {name!r} of {uri!r} is not in the description's packages")
        return Path(packages.ResolveUrl(uri))
    if uri.startswith("file://"):
        return Path(uri[len("file://"):])
    path = Path(uri)
    return path if path.is_absolute() else relative_to / path


def model_file(description: RobotDescription) -> Path:
    """The description's model file, resolved and checked readable.

    Raises
    ------
    ValueError
        Naming ``model`` when the file is missing, of a kind Drake does not parse, or not XML.
    """
    try:
        path = resolve_uri(description.model, package_map(description), relative_to=Path.cwd())
    except MissingRobotPackage:
        raise
    except (RuntimeError, ValueError) as error:
        raise ValueError(f"model: cannot resolve {description.model!r}: {error}") from error
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise ValueError(f"model: {path} is not a URDF, SDF or MJCF (.xml) file")
    if not path.is_file():
        raise ValueError(f"model: cannot read the model file {path}: no such file")
    try:
        ElementTree.parse(path)
    except (ElementTree.ParseError, OSError) as error:
        raise ValueError(f"model: cannot read the model file {path}: {error}") from error
    return path
