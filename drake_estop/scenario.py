"""Scenarios as data: one YAML document says what ``drake-estop simulate`` runs.

In the style of Drake's ``examples/hardware_sim`` (a scenario dataclass read
with ``pydrake.common.yaml.yaml_load_typed``): a :class:`Scenario` holds the
gait, the stop parameters, the signal time, the simulation mode and, for
physics runs, the plant configuration (Drake's ``MultibodyPlantConfig``) and
the perturbations of the simulated robot. Every field has a default, so a
scenario file names only what differs, e.g.::

    gait: {step_length: 0.3, step_time: 0.8}
    stop: {a_ss: 5.0, b_ss: 1000.0}
    estop_time: 3.4

``drake-estop simulate --scenario-file FILE.yaml`` (or ``--scenario-text
'{...}'``) starts from it; options given on the command line override it.
An unknown key is an error naming the key (``yaml_load_typed`` is strict),
and the parameter classes validate the values as everywhere else.

The project's parameter classes use postponed annotations and bare ``tuple``
fields, which ``yaml_load_typed`` cannot read directly; :func:`yaml_schema`
makes a schema twin of each (annotations resolved, tuples read as lists of the
element type of the default) and :func:`load_scenario` converts back.
"""

import dataclasses
import functools
import typing
from dataclasses import dataclass, field
from pathlib import Path

from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.multibody.plant import MultibodyPlantConfig

from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.planning.gait import Footstep, GaitParameters
from drake_estop.planning.planner import StopParameters
from drake_estop.planning.replan import MAX_REPLAN_SOLVES, check_solve_bound

SIMULATIONS = ("kinematic", "diagram", "physics")
CONTROLLERS = ("online", "offline-filter")


def default_plant_config() -> MultibodyPlantConfig:
    """The humanoid's plant: 1 ms discrete steps, SAP-based lagged contact, point contact between
    the sole-corner spheres and the ground (see :mod:`drake_estop.physics.plant`)."""
    return MultibodyPlantConfig(time_step=1e-3, contact_model="point", discrete_contact_approximation="lagged")


@dataclass
class Scenario:
    """Everything one ``drake-estop simulate`` run needs.

    Attributes
    ----------
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
    controller : str
        Physics only: ``"online"`` or ``"offline-filter"``.
    true_state : bool
        Physics only: feed the controller the true COG instead of the estimate.
    foot_compliance : bool
        Physics, online controller only: the stance ankles' foot-edge compliance (default on; off for
        comparison).
    swing_tilt : bool
        Physics, online controller only: the swing foot's tilt compensation (default on; off for comparison).
    measured_footholds : bool
        Physics, online controller only: re-plans after the landing stand on the estimated footholds
        (default on; off re-plans on the plan's feet, for comparison).
    recovery_step : bool
        Physics, online controller only: a re-plan after the landing that finds no double-support stop
        steps the rear foot forward (default on; off keeps the plan, for comparison).
    relanded_footholds : bool
        Physics, online controller only: a sole that lost contact after the landing and landed again off the
        plan's foothold re-plans the stop where it stands (default on; off for comparison).
    braked_landing : bool
        Physics, online controller only: the controller's braked landing
        (``drake_estop.physics.online.BRAKED_LANDING``; default on; off lands the paper's swing, for comparison).
    reference_fallback : bool
        Physics, online controller only: where no stop exists from the measured state at the signal, the
        latch plans the paper's stop from the reference and re-plans from the measured state (default on;
        off ends the run, exit status 2, for comparison).
    foothold_replan : bool
        Physics, online controller only: a sole measured off the plan's foot after the landing re-plans the
        stop on the measured feet (default off: net neutral on the campaign; on for comparison).
    max_replan_solves : int or None
        Physics, online controller only: stop solves a re-plan may do in one servo tick (default 2; the tries
        left go on at the next tick); null puts every try on one tick (for comparison).
    plant : MultibodyPlantConfig
        Physics only: the plant's ``time_step`` [s], ``contact_model`` (``"point"`` or
        ``"hydroelastic_with_fallback"``) and ``discrete_contact_approximation``.
    perturbations : Perturbations
        Physics only: pushes, mass and torso errors, friction, latency, noise.
    after_halt : float
        Seconds simulated and logged after the halt ends (>= 1).
    """

    gait: GaitParameters = field(default_factory=GaitParameters)
    stop: StopParameters = field(default_factory=StopParameters)
    estop_time: float | None = 3.4
    simulation: str = "diagram"
    controller: str = "online"
    true_state: bool = False
    foot_compliance: bool = True
    swing_tilt: bool = True
    measured_footholds: bool = True
    recovery_step: bool = True
    relanded_footholds: bool = True
    braked_landing: bool = True
    reference_fallback: bool = True
    foothold_replan: bool = False
    max_replan_solves: int | None = MAX_REPLAN_SOLVES
    plant: MultibodyPlantConfig = field(default_factory=default_plant_config)
    perturbations: Perturbations = field(default_factory=Perturbations)
    after_halt: float = 1.0

    def __post_init__(self):
        if self.simulation not in SIMULATIONS:
            raise ValueError(f"simulation must be one of {SIMULATIONS}, got {self.simulation!r}")
        if self.controller not in CONTROLLERS:
            raise ValueError(f"controller must be one of {CONTROLLERS}, got {self.controller!r}")
        check_solve_bound(self.max_replan_solves, "max_replan_solves")
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


def _field_type(cls, f, hints):
    hint = hints[f.name]
    if dataclasses.is_dataclass(hint):
        return yaml_schema(hint)
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
    fields = [(f.name, _field_type(cls, f, hints), dataclasses.field(default=None)) for f in dataclasses.fields(cls)]
    return dataclasses.make_dataclass(f"{cls.__name__}Schema", fields)


def _to_schema(value, cls):
    """``value`` (an instance of ``cls``) as an instance of its schema twin."""
    schema = yaml_schema(cls)
    if schema is cls:
        return value
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        item = getattr(value, f.name)
        if dataclasses.is_dataclass(hints[f.name]):
            item = _to_schema(item, hints[f.name])
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
        if dataclasses.is_dataclass(hint):
            item = _from_schema(item, hint)
        elif hint is tuple:
            element = _element_type(cls, f)
            item = tuple(_from_schema(x, _ORIGINAL[element]) if element in _ORIGINAL else x for x in item)
        kwargs[f.name] = item
    return cls(**kwargs)


_ORIGINAL = {}  # schema twin -> the class it stands for (filled below)


def _register(*classes):
    for cls in classes:
        _ORIGINAL[yaml_schema(cls)] = cls


def load_scenario(*, filename: str | Path | None = None, text: str | None = None,
                  defaults: Scenario | None = None) -> Scenario:
    """A :class:`Scenario` from a YAML file or string (exactly one), on top of ``defaults``.

    Parameters
    ----------
    filename : str or pathlib.Path, optional
        A YAML scenario file.
    text : str, optional
        The same, as a string, e.g. ``"{gait: {step_length: 0.2}, estop_time: 3.3}"`` (step length [m],
        signal time [s]).
    defaults : Scenario, optional
        What the document does not name (default: ``Scenario()``).

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
        schema = yaml_load_typed(schema=yaml_schema(Scenario), filename=None if filename is None else str(filename),
                                 data=text, defaults=_to_schema(defaults, Scenario))
        return _from_schema(schema, Scenario)
    except (RuntimeError, TypeError, ValueError, KeyError) as error:
        raise ValueError(f"{source}: {error}") from error


def dump_scenario(scenario: Scenario) -> str:
    """The scenario as YAML text (every field), readable by :func:`load_scenario`."""
    text = yaml_dump_typed(_to_schema(scenario, Scenario))
    # yaml_dump_typed leaves a None out, which would read back as the default: write it as null
    nulls = [f.name for f in dataclasses.fields(Scenario) if getattr(scenario, f.name) is None]
    return text + "".join(f"{name}: null\n" for name in nulls)


_register(Push, Perturbations, Footstep, GaitParameters, StopParameters, Scenario)
