"""Scenarios as data: one YAML document says what ``drake-estop simulate`` runs.

In the style of Drake's ``examples/hardware_sim`` (a scenario dataclass read
with ``pydrake.common.yaml.yaml_load_typed``): a :class:`Scenario` holds the
gait, the stop parameters, the signal time, the simulation mode and, for
physics runs, the controller and its features
(:class:`drake_estop.physics.controller_options.ControllerOptions`), the plant
configuration (Drake's ``MultibodyPlantConfig``) and the perturbations of the
simulated robot. Every field has a default, so a scenario file names only
what differs, e.g.::

    robot: default        # or g1, talos, or a description file (drake_estop.robots)
    gait: {step_length: 0.3, step_time: 0.8}
    stop: {a_ss: 5.0, b_ss: 1000.0}
    estop_time: 3.4
    simulation: physics
    controller:
      kind: online
      planner: {recovery_step: false}
      foot_compliance: null

``drake-estop simulate --scenario-file FILE.yaml`` (or ``--scenario-text
'{...}'``) starts from it; options given on the command line override it.
An unknown key is an error naming the key (``yaml_load_typed`` is strict),
and the parameter classes validate the values as everywhere else.

The ``robot`` names the humanoid; what the document leaves out of ``gait``
and ``stop`` is that robot's (:func:`scenario_for_robot`: its COG height,
steps, sole, arm swing, leg reach, crouch), so ``robot: g1`` alone walks and
stops the G1 as its description says.

The project's parameter classes use postponed annotations and bare ``tuple``
fields, which ``yaml_load_typed`` cannot read directly; :func:`yaml_schema`
makes a schema twin of each (annotations resolved, tuples read as lists of the
element type of the default) and :func:`load_scenario` converts back.
"""

import dataclasses
import functools
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.multibody.plant import MultibodyPlantConfig

from drake_estop.physics.controller_options import (
    ControllerOptions,
    FootEdgeComplianceConfig,
    FootForceConfig,
    HipStrategyConfig,
    SwingTiltConfig,
    check_key,
)
from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.planning.arms import ArmSwing
from drake_estop.planning.gait import Footstep, GaitParameters
from drake_estop.planning.planner import StopParameters
from drake_estop.systems.decision import StopPlannerConfig

SIMULATIONS = ("kinematic", "diagram", "physics")


def default_plant_config() -> MultibodyPlantConfig:
    """The humanoid's plant: 1 ms discrete steps, SAP-based lagged contact, point contact between
    the sole-corner spheres and the ground (see :mod:`drake_estop.physics.plant`)."""
    return MultibodyPlantConfig(time_step=1e-3, contact_model="point", discrete_contact_approximation="lagged")


@dataclass
class Scenario:
    """Everything one ``drake-estop simulate`` run needs.

    Attributes
    ----------
    robot : str
        The humanoid: ``default`` (the HRP-2-class model), ``g1``, ``talos`` or the path of a robot
        description YAML file (:func:`drake_estop.robots.load_robot`; in a scenario file, relative
        to its folder). Its gait and stop parameters are the defaults of ``gait`` and ``stop``.
    gait : GaitParameters
        The nominal walk (lengths in m, times in s).
    stop : StopParameters
        The stop planner's weights and limits.
    estop_time : float or None
        Time of the stop signal [s], latched at the next servo tick; None for no scheduled stop
        (only with a live Meshcat button).
    simulation : str
        ``"kinematic"`` (plan and roll out, numpy), ``"diagram"`` (the Drake diagram with IK) or
        ``"physics"`` (the humanoid with contact under the online controller).
    controller : ControllerOptions
        Physics only: the controller (``kind``: ``online`` or ``offline-filter``) and the online
        controller's features, each on or off (:class:`drake_estop.physics.controller_options.ControllerOptions`
        says what each does and why it defaults as it does).
    plant : MultibodyPlantConfig
        Physics only: the plant's ``time_step`` [s], ``contact_model`` (``"point"`` or
        ``"hydroelastic_with_fallback"``) and ``discrete_contact_approximation``.
    perturbations : Perturbations
        Physics only: pushes, mass and torso errors, friction, latency, noise.
    after_halt : float
        Seconds simulated and logged after the halt ends (>= 1).
    """

    robot: str = "default"
    gait: GaitParameters = field(default_factory=GaitParameters)
    stop: StopParameters = field(default_factory=StopParameters)
    estop_time: float | None = 3.4
    simulation: str = "diagram"
    controller: ControllerOptions = field(default_factory=ControllerOptions)
    plant: MultibodyPlantConfig = field(default_factory=default_plant_config)
    perturbations: Perturbations = field(default_factory=Perturbations)
    after_halt: float = 1.0

    def __post_init__(self):
        if not isinstance(self.robot, str) or not self.robot.strip():
            raise ValueError(f"robot must be a robot's name or a description file, got {self.robot!r}")
        if self.simulation not in SIMULATIONS:
            raise ValueError(f"simulation must be one of {SIMULATIONS}, got {self.simulation!r}")
        if not isinstance(self.controller, ControllerOptions):
            raise ValueError(f"controller must be a ControllerOptions (in YAML a mapping, e.g. "
                             f"{{kind: online, foot_compliance: null}}), got {self.controller!r}")
        if not self.after_halt >= 1.0:
            raise ValueError(f"after_halt must be at least 1 s, got {self.after_halt!r}")
        if self.estop_time is not None and not self.estop_time >= 0.0:
            raise ValueError(f"estop_time must be >= 0 s or null, got {self.estop_time!r}")
        contact = {"point": "point", "hydroelastic_with_fallback": "hydroelastic"}
        if self.plant.contact_model not in contact:
            raise ValueError(f"plant.contact_model must be 'point' or 'hydroelastic_with_fallback', "
                             f"got {self.plant.contact_model!r}")


# -- schema twins for yaml_load_typed --------------------------------------------------------

#: tuple fields whose default is empty: their element type
_TUPLE_ELEMENTS = {(Perturbations, "pushes"): Push, (GaitParameters, "footsteps"): Footstep}


def _element_type(cls, f):
    """The element type of a tuple field: listed above, else that of its default's items."""
    if (cls, f.name) in _TUPLE_ELEMENTS:
        return yaml_schema(_TUPLE_ELEMENTS[cls, f.name])
    default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
    kinds = {type(item) for item in default}
    if len(kinds) > 1:
        raise TypeError(f"tuple default {default!r} mixes element types")
    kind = kinds.pop() if kinds else float
    return yaml_schema(kind) if dataclasses.is_dataclass(kind) else kind


def _nested_dataclass(hint):
    """The dataclass of a field typed ``X`` or ``X | None`` with ``X`` a dataclass, else None."""
    if dataclasses.is_dataclass(hint):
        return hint
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        kinds = [k for k in typing.get_args(hint) if k is not type(None)]
        if len(kinds) == 1 and dataclasses.is_dataclass(kinds[0]):
            return kinds[0]
    return None


def _field_type(cls, f, hints):
    hint = hints[f.name]
    nested = _nested_dataclass(hint)
    if nested is not None:
        schema = yaml_schema(nested)
        return schema if nested is hint else schema | None
    if hint is tuple:
        return list[_element_type(cls, f)]
    return hint


@functools.cache
def yaml_schema(cls):
    """A dataclass ``yaml_load_typed`` can read in place of ``cls`` (see the module docstring).
    Drake's own bound types (``MultibodyPlantConfig``) are their own schema."""
    if not dataclasses.is_dataclass(cls):
        return cls
    hints = typing.get_type_hints(cls)
    fields = [(f.name, _field_type(cls, f, hints), _schema_default(f, hints[f.name])) for f in dataclasses.fields(cls)]
    return dataclasses.make_dataclass(f"{cls.__name__}Schema", fields)


def _schema_default(f, hint):
    """The schema twin's default of field ``f``: the original's, so that a section given as ``{}`` where the
    default is null reads as its class's defaults (None where the original has no default)."""
    if f.default is not dataclasses.MISSING:
        default = f.default
    elif f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    else:
        return dataclasses.field(default=None)
    nested = _nested_dataclass(hint)
    if default is not None and nested is not None:
        return dataclasses.field(default_factory=lambda: _to_schema(default, nested))
    if isinstance(default, tuple):
        return dataclasses.field(default_factory=lambda: [_to_schema(x, type(x)) if dataclasses.is_dataclass(x) else x
                                                          for x in default])
    return dataclasses.field(default=default)


def _to_schema(value, cls):
    """``value`` (an instance of ``cls``) as an instance of its schema twin."""
    schema = yaml_schema(cls)
    if schema is cls:
        return value
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        item = getattr(value, f.name)
        nested = _nested_dataclass(hints[f.name])
        if nested is not None and item is not None:
            item = _to_schema(item, nested)
        elif hints[f.name] is tuple:
            item = [_to_schema(x, type(x)) if dataclasses.is_dataclass(x) else x for x in item]
        kwargs[f.name] = item
    return schema(**kwargs)


def _from_schema(value, cls):
    """Back from the schema twin: lists to tuples, nested twins to the real classes (which validate)."""
    if yaml_schema(cls) is cls:
        return value
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        item = getattr(value, f.name)
        hint = hints[f.name]
        nested = _nested_dataclass(hint)
        if nested is not None and item is not None:
            item = _from_schema(item, nested)
        elif hint is tuple:
            element = _element_type(cls, f)
            item = tuple(_from_schema(x, _ORIGINAL[element]) if element in _ORIGINAL else x for x in item)
        kwargs[f.name] = item
    return cls(**kwargs)


_ORIGINAL = {}  # schema twin -> the class it stands for (filled below)


def _register(*classes):
    for cls in classes:
        _ORIGINAL[yaml_schema(cls)] = cls


def scenario_for_robot(robot: str, *, base: Scenario | None = None) -> Scenario:
    """``base`` (default ``Scenario()``) with ``robot`` and that robot's gait and stop parameters
    (:func:`drake_estop.robots.parameters.gait_parameters`, ``stop_parameters``).

    Raises
    ------
    ValueError
        Naming ``robot`` and the description's field when the robot cannot be loaded.
    """
    from drake_estop.robots.parameters import as_robot, gait_parameters, stop_parameters

    base = base or Scenario()
    try:
        description = as_robot(robot)
    except ValueError as error:
        raise ValueError(f"robot {robot!r}: {error}") from error
    return dataclasses.replace(base, robot=str(robot), gait=gait_parameters(description),
                               stop=stop_parameters(description))


def _document_robot(document, filename, robot) -> str | None:
    """The robot a scenario names: ``robot`` if given, else the document's ``robot`` (a description file
    relative to the scenario file's folder), else None."""
    if robot is not None:
        return str(robot)
    named = document.get("robot") if isinstance(document, dict) else None
    if not isinstance(named, str) or filename is None or not named.endswith((".yaml", ".yml")):
        return named if isinstance(named, str) else None
    path = Path(named)
    return str(path if path.is_absolute() else Path(filename).resolve().parent / path)


def load_scenario(*, filename: str | Path | None = None, text: str | None = None,
                  defaults: Scenario | None = None, robot: str | None = None) -> Scenario:
    """A :class:`Scenario` from a YAML file or string (exactly one), on top of ``defaults``.

    Parameters
    ----------
    filename : str or pathlib.Path, optional
        A YAML scenario file.
    text : str, optional
        The same, as a string, e.g. ``"{gait: {step_length: 0.2}, estop_time: 3.3}"`` (step length [m],
        signal time [s]).
    defaults : Scenario, optional
        What the document does not name (default: ``Scenario()``); when the document (or ``robot``)
        names another robot, its gait and stop are that robot's (:func:`scenario_for_robot`).
    robot : str, optional
        The robot, in place of the document's ``robot`` (the command line's ``--robot``).

    Returns
    -------
    Scenario
        Lengths in m, times in s, forces in N, as in the parameter classes.

    Raises
    ------
    ValueError
        Naming the key or the value that is wrong (unknown keys, wrong types, values the
        parameter classes reject).
    """
    if (filename is None) == (text is None):
        raise ValueError("load_scenario needs exactly one of filename= or text=")
    defaults = defaults or Scenario()
    source = f"scenario file {filename}" if filename is not None else "scenario text"
    try:
        document = yaml.safe_load(Path(filename).read_text() if text is None else text)
        if document is not None:
            _check_document(document, Scenario)
        named = _document_robot(document, filename, robot)
        if named is not None and named != defaults.robot:
            defaults = scenario_for_robot(named, base=defaults)
        schema = yaml_load_typed(schema=yaml_schema(Scenario), filename=None if filename is None else str(filename),
                                 data=text, defaults=_to_schema(defaults, Scenario))
        scenario = _from_schema(schema, Scenario)
        return dataclasses.replace(scenario, robot=named) if named is not None else scenario
    except (RuntimeError, TypeError, ValueError, KeyError, OSError, yaml.YAMLError) as error:
        raise ValueError(f"{source}: {error}") from error


#: the scalar field types a scenario document is checked against, and how an error names them
_SCALARS = {bool: "true or false", int: "a whole number", float: "a number", str: "a string"}


def _check_document(document, cls, path=()):
    """ValueError naming the first field of ``document`` that cannot be one of ``cls``'s: a section that is
    not a mapping (``controller: online``) or a scalar of the wrong kind (``estop_time: abc``), which
    yaml_load_typed reports without the field's name. Unknown keys and lists are left to it."""
    if not isinstance(document, dict):
        raise ValueError(f"{'.'.join(path) or 'the scenario'} must be a mapping of fields, got {document!r}")
    hints = typing.get_type_hints(cls)
    for key, value in document.items():
        if cls is ControllerOptions:
            check_key(key)  # names where a key of the controller's former flat form moved
        hint = hints.get(key)
        nested = _nested_dataclass(hint)
        if nested is None:
            _check_scalar(value, hint, (*path, key))
        elif value is not None or nested is hint:
            _check_section(value, nested, (*path, key), optional=nested is not hint)


def _check_section(value, cls, path, *, optional):
    if not isinstance(value, dict) and optional:
        raise ValueError(f"{'.'.join(path)} must be a mapping of its settings ({{}} for the defaults) or null "
                         f"(off), got {value!r}")
    _check_document(value, cls, path)


def _check_scalar(value, hint, path):
    union = typing.get_origin(hint) in (typing.Union, types.UnionType)
    kinds = typing.get_args(hint) if union else (hint,)
    kind = next((k for k in kinds if k in _SCALARS), None)
    if kind is None or (value is None and type(None) in kinds):
        return
    if kind is bool:
        fits = isinstance(value, bool)
    else:
        fits = isinstance(value, (int, float) if kind is float else kind) and not isinstance(value, bool)
    if not fits:
        allowed = _SCALARS[kind] + (" or null" if type(None) in kinds else "")
        raise ValueError(f"{'.'.join(path)} must be {allowed}, got {value!r}")


def dump_scenario(scenario: Scenario) -> str:
    """The scenario as YAML text (every field), readable by :func:`load_scenario`."""
    lines = yaml_dump_typed(_to_schema(scenario, Scenario)).splitlines()
    # yaml_dump_typed leaves a None out, which would read back as the default: write it as null
    for path in _null_paths(scenario):
        indent, start, end = "", 0, len(lines)
        for key in path[:-1]:  # the block of the mapping that holds the field (two spaces a level)
            start = lines.index(f"{indent}{key}:", start, end) + 1
            indent += "  "
            end = next((i for i in range(start, end) if not lines[i].startswith(indent)), end)
        lines.insert(end, f"{indent}{path[-1]}: null")
    return "\n".join(lines) + "\n"


def _null_paths(value, path=()) -> list:
    """The key paths of the None fields of the dataclass ``value`` and of the dataclasses in it."""
    paths = []
    for f in dataclasses.fields(value):
        item = getattr(value, f.name)
        if item is None:
            paths.append((*path, f.name))
        elif dataclasses.is_dataclass(item):
            paths += _null_paths(item, (*path, f.name))
    return paths


_register(Push, Perturbations, Footstep, ArmSwing, GaitParameters, StopParameters, StopPlannerConfig, SwingTiltConfig,
          FootForceConfig, FootEdgeComplianceConfig, HipStrategyConfig, ControllerOptions, Scenario)
