"""drake_estop: emergency stop for walking humanoids (Morisawa et al., IROS 2005) on Drake.

The public API, for scripts, notebooks and system-level tests::

    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from drake_estop import AddEmergencyStop

    builder = DiagramBuilder()
    estop = AddEmergencyStop(builder, estop_time=3.4)
    simulator = Simulator(builder.Build())

Building blocks (Drake LeafSystems): `WalkingPatternSource`, `EStopTrigger`,
`StopPlannerSystem` (its settings a `StopPlannerConfig`, its mode a `StopMode`), `WholeBodyIK`;
parameters: `GaitParameters`,
`StopParameters`, `Sole`, `ArmSwing`, `PhysicsParameters`, `Perturbations`, `Push`;
robots as data: `RobotDescription`, `load_robot` (``default``, ``g1``,
``talos`` or a YAML file) and `add_robot` (``AddEmergencyStop(robot=...)``
runs any of them);
the planner itself: `plan_stop` returning a `StopPlan` (or raising
`InfeasibleStop`), and `one_step_feasible`, whether a signal now would stop
within one step; the online controller on the simulated robot: `run_online`
(``drake-estop simulate --physics`` from Python) with
`controller_stop_parameters` and `ControllerOptions` (a scenario's
``controller`` section: the planner's `StopPlannerConfig`, and each reflex's
config, `SwingTiltConfig`, `FootForceConfig`, `FootEdgeComplianceConfig`,
`HipStrategyConfig`, or None for off); what can be caught
at all: `capturability` / `state_capturability` (N-step capturability with
finite feet, `SteppingLimits`, a `Capturability` verdict) and the
`CapturabilityMonitor` system; the paper-style figures `plot_cog_zmp` and
`plot_knees`. World frame x
forward, y left, z up; SI units throughout (m, s, rad, N).

Names are imported on first use (PEP 562), so ``import drake_estop`` stays
cheap; ``from drake_estop import X`` works for every name in ``__all__``.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it (the package's current layout)
_EXPORTS = {
    "AddEmergencyStop": "drake_estop.api",
    "EmergencyStop": "drake_estop.api",
    "EmergencyStopLog": "drake_estop.api",
    "WalkingPatternSource": "drake_estop.systems.reference",
    "EStopTrigger": "drake_estop.systems.trigger",
    "StopPlannerSystem": "drake_estop.systems.stop_controller",
    "StopPlannerConfig": "drake_estop.systems.decision",
    "StopMode": "drake_estop.systems.decision",
    "WholeBodyIK": "drake_estop.systems.ik",
    "StopVisualizer": "drake_estop.systems.visualization",
    "GaitParameters": "drake_estop.planning.gait",
    "Sole": "drake_estop.planning.gait",
    "NominalPattern": "drake_estop.planning.gait",
    "ArmSwing": "drake_estop.planning.arms",
    "RobotDescription": "drake_estop.robots.description",
    "load_robot": "drake_estop.robots.parameters",
    "add_robot": "drake_estop.robots.plant",
    "StopParameters": "drake_estop.planning.plan",
    "StopPlan": "drake_estop.planning.plan",
    "InfeasibleStop": "drake_estop.planning.plan",
    "PHASES": "drake_estop.planning.plan",
    "plan_stop": "drake_estop.planning.planner",
    "one_step_feasible": "drake_estop.planning.planner",
    "PhysicsParameters": "drake_estop.physics.plant",
    "run_online": "drake_estop.physics.online",
    "build_online_diagram": "drake_estop.physics.online",
    "controller_stop_parameters": "drake_estop.physics.online",
    "ControllerOptions": "drake_estop.physics.controller_options",
    "SwingTiltConfig": "drake_estop.physics.controller_options",
    "FootForceConfig": "drake_estop.physics.controller_options",
    "FootEdgeComplianceConfig": "drake_estop.physics.controller_options",
    "HipStrategyConfig": "drake_estop.physics.controller_options",
    "Perturbations": "drake_estop.physics.perturbations",
    "Push": "drake_estop.physics.perturbations",
    "Scenario": "drake_estop.scenario",
    "load_scenario": "drake_estop.scenario",
    "load_humanoid": "drake_estop.model",
    "make_meshcat": "drake_estop.systems.visualization",
    "plot_cog_zmp": "drake_estop.systems.visualization",
    "plot_knees": "drake_estop.systems.visualization",
    "SteppingLimits": "drake_estop.planning.capturability",
    "Capturability": "drake_estop.planning.capturability",
    "capturability": "drake_estop.planning.capturability",
    "state_capturability": "drake_estop.planning.capturability",
    "CapturabilityMonitor": "drake_estop.systems.capturability_monitor",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name):
    """Import a public name from its module on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'drake_estop' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
