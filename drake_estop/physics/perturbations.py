"""Perturbations of the SIMULATED robot only.

The controller keeps the nominal model; everything here changes the physics
plant (its Context parameters, the ground friction, an external force) or
the sensors (:mod:`drake_estop.physics.sensors`: noise and latency).

* :class:`Push` / :class:`Perturbations`: the settings, validated on
  construction; every ``ValueError`` names the command-line option
  (``--mass-scale``, ``--push``, ...) so that the CLI can print it and exit
  with status 2.
* :func:`add_perturbation_arguments` / :func:`perturbations_from_args`: the
  ``argparse`` options of ``simulate --physics``.
* :func:`apply_model_errors`: link masses, torso mass and torso COM, written
  into the plant's *Context* (``RigidBody.SetSpatialInertiaInBodyFrame``);
  the plant's default (nominal) parameters are untouched, so a controller
  that uses ``plant.CreateDefaultContext()`` keeps the nominal model.
* :func:`ground_friction`: the ground's friction coefficients for ``--friction``;
  :func:`perturbed_ground`: those and the floor's drop (``--floor-drop``).
* :class:`PelvisPush` / :func:`add_pelvis_push`: the pushes, as a force on
  the pelvis COM through the plant's ``applied_spatial_force`` input port.

Wiring (the lead's diagram)::

    perturbations = perturbations_from_args(args)          # ValueError -> exit 2
    physics = perturbed_ground(perturbations, physics)     # before add_physics_plant
    plant, scene_graph, instance, ground_id = add_physics_plant(builder, physics)
    push = add_pelvis_push(builder, plant, perturbations.pushes)
    ...
    diagram = builder.Build(); simulator = Simulator(diagram)
    plant_context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    apply_model_errors(plant, plant_context, perturbations)   # before Initialize()
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from dataclasses import dataclass, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.multibody.tree import BodyIndex, SpatialInertia
from pydrake.systems.framework import LeafSystem

from drake_estop.physics.plant import FloorDrop
from drake_estop.robots.parameters import as_robot
from drake_estop.robots.plant import SOLE_FRICTION

#: Friction coefficients of the soles' contact geometry: models/humanoid.urdf's, and the contact
#: :func:`drake_estop.robots.add_robot` adds to the other robots' soles (the same numbers).
SOLE_MU_STATIC, SOLE_MU_DYNAMIC = SOLE_FRICTION
_TIME_TOLERANCE = 1e-9  # [s]
#: Largest |--torso-com-offset| accepted [m].
MAX_TORSO_COM_OFFSET = 0.1


def finite_number(value) -> bool:
    """Whether ``value`` reads as a finite float (False for NaN, inf and what is not a number)."""
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


@dataclass(frozen=True)
class Push:
    """A constant force on the pelvis COM, world frame, during [time, time + duration).

    The impulse is ``force * duration`` [N s]; on the 58 kg robot a push of
    17 N s changes the COG velocity by about 0.3 m/s.

    Attributes
    ----------
    time : float
        Start of the push [s].
    force_x, force_y : float
        World-frame force [N].
    duration : float
        Length of the push [s], > 0.
    """

    time: float
    force_x: float
    force_y: float
    duration: float

    def __post_init__(self):
        for name in ("time", "force_x", "force_y", "duration"):
            if not finite_number(getattr(self, name)):
                raise ValueError(f"--push: {name} must be a finite number, got {getattr(self, name)!r}")
        if not self.duration > 0:
            raise ValueError(f"--push: duration must be > 0 s, got {self.duration!r}")

    @property
    def impulse(self) -> np.ndarray:
        """[N s] in world x, y."""
        return np.array([self.force_x, self.force_y]) * self.duration

    def active(self, t: float) -> bool:
        """True during [time, time + duration), with a 1e-9 s tolerance so that a push on the plant's
        1 ms grid acts for exactly duration / time_step steps despite floating-point sums."""
        return self.time - _TIME_TOLERANCE <= t < self.time + self.duration - _TIME_TOLERANCE


@dataclass(frozen=True)
class Perturbations:
    """Everything that makes the simulated robot differ from the controller's model.

    Attributes
    ----------
    pushes : tuple of Push
        Pelvis pushes (``--push``, repeatable).
    mass_scale : float
        Factor (> 0, dimensionless) on every link's mass and rotational
        inertia (``--mass-scale``).
    torso_mass_scale : float
        Factor (> 0) on the torso's mass and inertia, on top of
        ``mass_scale`` (``--torso-mass-scale``).
    torso_com_offset : float
        Torso COM moved along the torso frame's x axis [m], forward positive,
        abs value <= 0.1 m (``--torso-com-offset``).
    friction : float or None
        Effective foot-ground friction coefficient (dimensionless, in (0, 1.6);
        None for the model's 1.0 / 0.8; ``--friction``, see
        :func:`ground_friction`).
    latency_ticks : int
        Servo ticks between sensing and the estimator output, >= 0 (``--latency``).
    sensor_noise : bool
        White noise on encoders [rad] / gyro [rad/s] / accelerometer [m/s^2]
        (``--sensor-noise``).
    seed : int
        The noise seed, >= 0 (``--seed``).
    floor_drop : FloorDrop or None
        A rectangle of the floor lower than the plan's ``z = 0`` (``--floor-drop``; None: a flat floor).
    """

    pushes: tuple = ()
    mass_scale: float = 1.0
    torso_mass_scale: float = 1.0
    torso_com_offset: float = 0.0
    friction: float | None = None
    latency_ticks: int = 0
    sensor_noise: bool = False
    seed: int = 0
    floor_drop: FloorDrop | None = None

    def __post_init__(self):
        pushes = tuple(p if isinstance(p, Push) else Push(*p) for p in self.pushes)
        object.__setattr__(self, "pushes", pushes)
        if self.floor_drop is not None and not isinstance(self.floor_drop, FloorDrop):
            object.__setattr__(self, "floor_drop", FloorDrop(*self.floor_drop))
        for option, name in (("--mass-scale", "mass_scale"), ("--torso-mass-scale", "torso_mass_scale")):
            value = getattr(self, name)
            if not (finite_number(value) and float(value) > 0):
                raise ValueError(f"{option} must be a finite number > 0, got {value!r}")
        if not (finite_number(self.torso_com_offset) and abs(float(self.torso_com_offset)) <= MAX_TORSO_COM_OFFSET):
            raise ValueError(f"--torso-com-offset must be finite with |DX| <= {MAX_TORSO_COM_OFFSET} m, "
                             f"got {self.torso_com_offset!r}")
        if self.friction is not None:
            limit = 2 * SOLE_MU_DYNAMIC
            if not (finite_number(self.friction) and 0 < float(self.friction) < limit):
                raise ValueError(f"--friction must be a finite number in (0, {limit:g}) (the soles' own "
                                 f"coefficient is {SOLE_MU_DYNAMIC:g}), got {self.friction!r}")
        if not (isinstance(self.latency_ticks, (int, np.integer)) and not isinstance(self.latency_ticks, bool)
                and self.latency_ticks >= 0):
            raise ValueError(f"--latency must be an integer number of ticks >= 0, got {self.latency_ticks!r}")
        if not (isinstance(self.seed, (int, np.integer)) and not isinstance(self.seed, bool) and self.seed >= 0):
            raise ValueError(f"--seed must be an integer >= 0, got {self.seed!r}")

    def summary(self) -> dict:
        """The perturbations as JSON-ready values (for run summaries)."""
        return {"pushes": [[p.time, p.force_x, p.force_y, p.duration] for p in self.pushes],
                "mass_scale": self.mass_scale, "torso_mass_scale": self.torso_mass_scale,
                "torso_com_offset": self.torso_com_offset, "friction": self.friction,
                "latency_ticks": self.latency_ticks, "sensor_noise": self.sensor_noise, "seed": self.seed,
                "floor_drop": None if self.floor_drop is None else list(dataclasses.astuple(self.floor_drop))}

    @property
    def model_error(self) -> bool:
        """True if :func:`apply_model_errors` changes anything."""
        return (self.mass_scale != 1.0 or self.torso_mass_scale != 1.0 or self.torso_com_offset != 0.0)


# --------------------------------------------------------------------------
# Command line.


def add_perturbation_arguments(parser: argparse.ArgumentParser,
                               defaults: Perturbations | None = None) -> argparse.ArgumentParser:
    """Add ``--push``, ``--mass-scale``, ... (the robustness matrix's perturbations) to ``parser``,
    defaulting to ``defaults`` (a scenario's perturbations; ``--push`` adds to its pushes)."""
    d = defaults or Perturbations()
    group = parser.add_argument_group("perturbations of the simulated robot (--physics)")
    group.add_argument("--push", nargs=4, type=float, action="append",
                       default=[[p.time, p.force_x, p.force_y, p.duration] for p in d.pushes],
                       metavar=("TIME", "FX", "FY", "DURATION"),
                       help="force on the pelvis, world frame [s N N s]; repeatable")
    group.add_argument("--mass-scale", type=float, default=d.mass_scale, metavar="F", help="scales all link masses")
    group.add_argument("--torso-mass-scale", type=float, default=d.torso_mass_scale, metavar="F",
                       help="scales the torso's mass")
    group.add_argument("--torso-com-offset", type=float, default=d.torso_com_offset, metavar="DX",
                       help="moves the torso COM [m], forward positive")
    group.add_argument("--friction", type=float, default=d.friction, metavar="MU",
                       help="foot-ground friction coefficient (default: the model's 0.8 dynamic)")
    group.add_argument("--latency", type=int, default=d.latency_ticks, metavar="TICKS",
                       help="sensor-to-command delay [ticks]")
    group.add_argument("--sensor-noise", action="store_true", default=d.sensor_noise,
                       help="white noise: encoders 1e-3 rad, gyro 0.01 rad/s, accelerometer 0.05 m/s^2")
    group.add_argument("--seed", type=int, default=d.seed, metavar="N", help="seed for the sensor noise")
    group.add_argument("--floor-drop", nargs=5, type=float,
                       default=None if d.floor_drop is None else list(dataclasses.astuple(d.floor_drop)),
                       metavar=("X_MIN", "X_MAX", "Y_MIN", "Y_MAX", "DEPTH"),
                       help="the floor DEPTH [m] lower over that rectangle (world frame [m])")
    return parser


def perturbations_from_args(args) -> Perturbations:
    """:class:`Perturbations` from parsed arguments; ValueError (naming the option) if meaningless."""
    return Perturbations(
        pushes=tuple(Push(*values) for values in (args.push or [])),
        mass_scale=args.mass_scale, torso_mass_scale=args.torso_mass_scale,
        torso_com_offset=args.torso_com_offset, friction=args.friction, latency_ticks=args.latency,
        sensor_noise=bool(args.sensor_noise), seed=args.seed,
        floor_drop=None if args.floor_drop is None else FloorDrop(*args.floor_drop))


# --------------------------------------------------------------------------
# Model errors.


def apply_model_errors(plant, plant_context, perturbations: Perturbations, robot=None):
    """Write the perturbed inertias into ``plant_context`` (the plant's defaults stay nominal).

    Every rigid body's mass and rotational inertia are multiplied by
    ``mass_scale`` (COM unchanged); the torso (``robot``'s ``torso_body``, the
    default humanoid's ``torso`` when ``robot`` is None) additionally
    by ``torso_mass_scale``, and its COM is moved by ``torso_com_offset``
    along the torso frame's x axis (central inertia kept). Call it on the
    simulated plant's context before ``Simulator.Initialize()``. Returns the
    list of bodies changed.
    """
    changed = []
    if not perturbations.model_error:
        return changed
    torso = plant.GetBodyByName(as_robot(robot).torso_body)
    for index in range(1, plant.num_bodies()):  # 0 is the world body
        body = plant.get_body(BodyIndex(index))
        M = body.CalcSpatialInertiaInBodyFrame(plant_context)
        mass = M.get_mass()
        if mass == 0:
            continue
        p = M.get_com()
        central = M.Shift(p).CalcRotationalInertia()  # about the COM, body frame
        scale = perturbations.mass_scale
        if body.index() == torso.index():
            scale *= perturbations.torso_mass_scale
            p = p + np.array([perturbations.torso_com_offset, 0.0, 0.0])
        body.SetSpatialInertiaInBodyFrame(
            plant_context, SpatialInertia.MakeFromCentralInertia(mass * scale, p, central * scale))
        changed.append(body)
    return changed


# --------------------------------------------------------------------------
# Friction.


def ground_coefficient(mu: float, sole_mu: float = SOLE_MU_DYNAMIC) -> float:
    """Ground coefficient g with Drake's pair rule ``2 g s / (g + s) = mu`` against the sole's ``s``."""
    if not 0 < mu < 2 * sole_mu:
        raise ValueError(f"--friction must be in (0, {2 * sole_mu:g}), got {mu!r}")
    return mu * sole_mu / (2 * sole_mu - mu)


def ground_friction(perturbations: Perturbations, physics_params):
    """``physics_params`` with the ground friction that realises ``--friction MU``.

    Drake combines the two geometries of a contact pair as
    ``mu = 2 mu_ground mu_sole / (mu_ground + mu_sole)``
    (``CalcContactFrictionFromSurfaceProperties``), and the soles carry
    their own 1.0 static / 0.8 dynamic in the model file. The discrete SAP
    solver (``kLagged``, :func:`drake_estop.physics.plant.add_physics_plant`)
    uses only the *dynamic* coefficient (it has no stiction). So the
    ground's dynamic coefficient is solved for an effective dynamic
    coefficient of exactly MU against the sole's 0.8 (possible for
    MU < 1.6); its static coefficient is set equal (``PhysicsParameters``
    needs mu_dynamic <= mu_static), which SAP ignores. With
    ``friction=None`` the parameters are returned unchanged (effective
    1.0 / 0.8).
    """
    if perturbations.friction is None:
        return physics_params
    g = ground_coefficient(float(perturbations.friction))
    return replace(physics_params, mu_static=g, mu_dynamic=g)


def perturbed_ground(perturbations: Perturbations, physics_params):
    """``physics_params`` with the ground the perturbations ask for: the friction (:func:`ground_friction`)
    and the floor's drop (``floor_drop``). Unchanged (the same object) without either."""
    physics_params = ground_friction(perturbations, physics_params)
    if perturbations.floor_drop is None:
        return physics_params
    return replace(physics_params, floor_drop=perturbations.floor_drop)


# --------------------------------------------------------------------------
# Pushes.


class PelvisPush(LeafSystem):
    """Pushes on the pelvis COM, through the plant's applied-spatial-force input.

    .. pydrake_system::

        name: PelvisPush
        output_ports:
        - applied_spatial_force

    ``applied_spatial_force`` (abstract ``list[ExternallyAppliedSpatialForce]``):
    for every push active at the context time (``time <= t < time +
    duration``) a force ``[force_x, force_y, 0]`` N (world frame, no
    moment) applied at the COM of body ``body_name`` (default the floating
    base of ``robot``, a description, a name or None: the default humanoid's
    pelvis). Several active pushes give several
    entries (Drake sums them). Connect it to
    ``plant.get_applied_spatial_force_input_port()``.

    The COM is the plant's default (nominal) one, read at construction; with
    a mass-scale perturbation the body COM does not move, so the point is
    the same.

    The output depends on time only. The discrete plant samples it at each
    of its 1 ms steps, so a push of duration ``d`` acts for
    ``d / time_step`` plant steps when the push time and duration are on
    the 1 ms grid (exact impulse: measured Delta v = impulse / mass to
    1e-4 on the humanoid in the air).
    """

    def __init__(self, *, plant, pushes=(), body_name: str | None = None, robot=None):
        super().__init__()
        body_name = as_robot(robot).floating_base if body_name is None else body_name
        self.pushes = tuple(p if isinstance(p, Push) else Push(*p) for p in pushes)
        body = plant.GetBodyByName(body_name)
        self._body_index = body.index()
        self._p_BoBcm_B = np.asarray(body.default_com(), float)
        self.applied_spatial_force_port = self.DeclareAbstractOutputPort(
            "applied_spatial_force", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            # without pushes the (empty) output is constant: computed once, not at every plant step
            self._calc, prerequisites_of_calc={self.time_ticket() if self.pushes else self.nothing_ticket()})

    def force_at(self, t: float) -> np.ndarray:
        """Total push force [N] (world x, y, z) at time ``t``."""
        total = np.zeros(3)
        for push in self.pushes:
            if push.active(t):
                total[:2] += (push.force_x, push.force_y)
        return total

    def _calc(self, context, output):
        t = context.get_time()
        forces = []
        for push in self.pushes:
            if not push.active(t):
                continue
            applied = ExternallyAppliedSpatialForce()
            applied.body_index = self._body_index
            applied.p_BoBq_B = self._p_BoBcm_B
            applied.F_Bq_W = SpatialForce(np.zeros(3), np.array([push.force_x, push.force_y, 0.0]))
            forces.append(applied)
        output.set_value(forces)


def add_pelvis_push(builder, plant, pushes, *, name: str = "pelvis_push", robot=None) -> PelvisPush:
    """Add a :class:`PelvisPush` (on ``robot``'s floating base) and connect it to ``plant``'s
    applied-spatial-force input.

    Returns the system. With no pushes it is still added (its output is an
    empty list), so the diagram has the same structure in every run.
    """
    system = builder.AddNamedSystem(name, PelvisPush(plant=plant, pushes=pushes, robot=robot))
    builder.Connect(system.applied_spatial_force_port, plant.get_applied_spatial_force_input_port())
    return system
