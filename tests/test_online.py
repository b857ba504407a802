"""The online controller in physics: the default `simulate --physics` diagram, its every-tick work and
estimate, and ``run_online``'s arguments."""

import numpy as np
import pytest

from drake_estop.physics import offline
from drake_estop.physics.controller_options import ControllerOptions
from drake_estop.physics.criteria import CRITERIA
from drake_estop.physics.online import (
    build_online_diagram,
    controller_stop_parameters,
    joint_velocity_violations,
    online_simulator,
    run_online,
)
from drake_estop.physics.perturbations import Perturbations, Push
from drake_estop.planning.gait import GaitParameters, NominalPattern
from drake_estop.planning.plan import StopParameters


def _online_with_nothing_ahead(estop_time):
    """The paper's stop at ``estop_time`` with the online controller, with everything computed after the
    signal forbidden: the offline joint reference (IK over the rollout), the preview filter and
    the nominal-walk error cache must never be called."""
    mp = pytest.MonkeyPatch()

    def forbidden(*args, **kwargs):
        raise AssertionError("the online controller computed a reference ahead of time")

    for name in ("reference_for", "joint_reference", "_zmp_error", "_nominal_errors", "nominal_rollout"):
        mp.setattr(offline, name, forbidden)
    mp.setattr(offline.ZmpPreviewFilter, "track", forbidden)
    try:
        return run_online(estop_time=estop_time, pattern=NominalPattern())
    finally:
        mp.undo()


@pytest.fixture(scope="module")
def paper_stop():
    """The paper's 3.4 s stop (late single support), online, nothing computed ahead of its tick."""
    return _online_with_nothing_ahead(3.4)


@pytest.mark.slow
def test_paper_stop_at_3_5_s_meets_every_criterion_online():
    """The paper's second scenario (3.5 s, just after the touchdown: double support), online."""
    result = _online_with_nothing_ahead(3.5)
    assert result.plan.support == "double"
    assert result.criteria == {name: True for name in CRITERIA}
    assert result.online["joint_velocity_violations"] == 0
    assert result.numbers()["final_cog_offset_m"] < 0.02


@pytest.mark.slow
def test_paper_stop_meets_every_criterion_online(paper_stop):
    assert paper_stop.criteria == {name: True for name in CRITERIA}
    numbers = paper_stop.numbers()
    assert numbers["final_cog_offset_m"] < 0.01
    assert numbers["torso_tilt_max_rad"] < 0.05
    # unpushed, the loaded soles stand where the plan puts them, headed as it heads them
    assert numbers["sole_off_plan_max_m"] < 0.005 and numbers["sole_turn_max_rad"] < 0.01


def test_online_controller_works_every_tick_and_reports_its_cost(paper_stop):
    online = paper_stop.online
    assert online["controller"] == "online"
    tick = online["tick_compute"]
    dt = paper_stop.plan.params.servo_period
    span = paper_stop.times[-1] - paper_stop.plan.signal_time
    # one entry per servo tick from the signal on: the estimator, planner and IK run every tick
    assert tick["ticks"] == pytest.approx(span / dt, abs=2)
    assert 0 < tick["median"] <= tick["p99"] <= tick["max"]
    cpu = online["tick_compute_cpu"]  # the same ticks in the thread's CPU time
    assert cpu["ticks"] == tick["ticks"] and 0 < cpu["median"] <= cpu["p99"] <= cpu["max"]
    blocks = online["tick_compute_by_block"]  # where that CPU time goes, block by block
    assert {"WholeBodyIK._update", "StateEstimator._calc_estimate", "StopPlannerSystem._update",
            "StopPlannerSystem.reference"} <= set(blocks)  # the planner's reference: a cache, timed as its own
    assert all(seconds > 0 for seconds in blocks.values())
    assert sum(blocks.values()) == pytest.approx(cpu["mean"], rel=1e-9)
    slowest = online["tick_compute_slowest"]  # the worst ticks, what each spent its time on
    assert len(slowest) == 3 and slowest[0]["total"] == pytest.approx(cpu["max"], rel=1e-12)
    assert slowest[0]["t"] == pytest.approx(cpu["max_at"]) and slowest[0]["t"] >= paper_stop.plan.signal_time
    assert set(slowest[0]["blocks"]) <= set(blocks)
    assert online["replans"] >= 0 and online["replan_failures"] >= 0
    assert online["joint_velocity_violations"] == 0
    assert paper_stop.criteria["joint_speed_within_limits"]  # the criterion is that count being 0


def test_every_tick_times_both_of_its_state_estimates(monkeypatch):
    """A tick estimates the state twice (:func:`drake_estop.physics.plant.plant_config`): for the
    planner's unrestricted update, from the robot before the plant's step, and in the estimator's
    discrete update after it. Both count in the tick's compute time, also where a logger's publish
    (outside every update) computes the first one."""
    import time

    from pydrake.systems.analysis import Simulator

    from drake_estop.physics.estimation import StateEstimator

    steps = []
    original = StateEstimator._step

    def slow(self, context, x, t):  # a 3 ms estimate
        steps.append(t)
        time.sleep(0.003)
        return original(self, context, x, t)
    monkeypatch.setattr(StateEstimator, "_step", slow)
    params = controller_stop_parameters()
    handles = build_online_diagram(NominalPattern(), params, None)
    simulator = Simulator(handles.diagram)
    context = simulator.get_mutable_context()
    handles.plant.SetPositions(handles.plant.GetMyMutableContextFromRoot(context), handles.initial_q)
    simulator.Initialize()
    simulator.AdvanceTo(0.2)
    ticks = np.rint(np.array(steps) / params.servo_period).astype(int)
    # ticks 0-39 two estimates each (AdvanceTo(0.2) stops after the publish of tick 40, before its updates)
    assert np.array_equal(np.bincount(ticks)[:40], np.full(40, 2))
    per_tick = handles.timer.per_tick(clock="wall")[:40]
    assert len(per_tick) == 40 and np.all(per_tick >= 0.006)


def test_one_step_feasible_logged_every_tick_online(paper_stop):
    """The planner's one_step_feasible per servo tick from 0 (row k: a signal at tick k); it plans
    from the estimated state where that has left the reference, so only the latch is checked exactly."""
    column = paper_stop.online["one_step_feasible"]
    plan = paper_stop.plan
    dt = plan.params.servo_period
    assert len(column) >= round(paper_stop.times[-1] / dt) - 1
    assert set(np.unique(column)) == {0.0, 1.0}  # the walk before 3.4 s has next-step ticks (e.g. 3.2 s)
    latched = int(round(plan.signal_time / dt)) + 1
    first = getattr(plan, "plans", (plan,))[0]
    assert np.all(column[latched:] == float(first.case == "one-step"))


def test_the_stops_mode_is_logged_every_tick_online(paper_stop):
    """The planner's mode per tick and where it changed: walking until the latch of 3.4 s, then the
    paper's stop phase by phase (the physics may re-plan, but the paper's stop lands once)."""
    dt = paper_stop.plan.params.servo_period
    modes = [change["mode"] for change in paper_stop.online["modes"]]
    # the trigger's latch is its state: the planner sees the 3.4 s signal at the next tick
    assert modes[0] == "walking" and paper_stop.online["modes"][1]["time"] == pytest.approx(3.4 + dt)
    assert modes[1:4] == ["single_support_stop", "double_support_stop", "halt"]
    assert paper_stop.online["mode"].shape[1] == 2
    assert paper_stop.online["mode"][int(round(3.3 / dt))].tolist() == [0.0, 0.0]


def test_joint_velocity_violations_counts_ticks_over_the_model_limit(paper_stop):
    from pydrake.multibody.plant import MultibodyPlant

    from drake_estop.model import load_humanoid

    plant = MultibodyPlant(0.001)
    load_humanoid(plant)
    plant.Finalize()
    states = np.zeros((3, plant.num_multibody_states()))
    limit = plant.GetVelocityUpperLimits()
    joint = int(np.flatnonzero(np.isfinite(limit))[0])
    states[1, plant.num_positions() + joint] = 1.01 * limit[joint]
    states[2, plant.num_positions() + joint] = -0.99 * limit[joint]
    np.testing.assert_array_equal(joint_velocity_violations(plant, states), [0, 1, 0])


def test_the_estimator_follows_the_true_cog(paper_stop):
    estimate = paper_stop.online["com_est"]
    n = min(len(estimate), len(paper_stop.times))
    true = np.column_stack([paper_stop.com_meas_x, paper_stop.com_meas_y])[:n]
    error = np.linalg.norm(estimate[:n, :2] - true, axis=1)
    assert np.max(error[10:]) < 0.01  # after the first ticks (the filter starts)


def test_pushes_go_through_the_plants_applied_spatial_force_input():
    handles = build_online_diagram(NominalPattern(), controller_stop_parameters(), 3.4,
                                   perturbations=Perturbations(pushes=(Push(3.4, 50.0, 0.0, 0.1),)))
    connections = handles.diagram.connection_map()
    port = handles.plant.get_applied_spatial_force_input_port()
    source = connections[(handles.plant, port.get_index())]
    assert source[0] is handles.push
    context = handles.push.CreateDefaultContext()
    context.SetTime(3.45)
    forces = handles.push.applied_spatial_force_port.Eval(context)
    assert len(forces) == 1
    np.testing.assert_allclose(forces[0].F_Bq_W.translational(), [50.0, 0.0, 0.0])


@pytest.mark.parametrize("arguments, named", [
    ({"estop_time": float("nan")}, "estop_time"),
    ({"estop_time": -0.1}, "estop_time"),
    ({"estop_time": 100.0}, "estop_time"),  # past the walk's end
    ({"estop_time": "3.4 s"}, "estop_time"),
    ({"after_halt": 0.5}, "after_halt"),
    ({"after_halt": float("inf")}, "after_halt"),
    ({"controller": "online"}, "controller must be a ControllerOptions"),
    ({"controller": ControllerOptions(kind="offline-filter")}, "controller.kind"),
    ({"gait_params": GaitParameters(step_length=0.2), "pattern": NominalPattern()}, "gait_params and pattern"),
    # a feature that acts through the stop parameters is not silently dropped with stop parameters of one's own
    ({"stop_params": StopParameters()}, r"controller.braked_landing is True but stop_params have no braked"),
    ({"stop_params": controller_stop_parameters(), "controller": ControllerOptions(braked_landing=False)},
     r"braked_landing is False but stop_params have the braked landing.*braked_landing=False\)"),
])
def test_run_online_rejects_bad_arguments_naming_them(arguments, named, monkeypatch):
    import drake_estop.physics.online as online

    def no_build(*args, **kwargs):
        raise AssertionError("built a diagram from bad arguments")

    monkeypatch.setattr(online, "build_online_diagram", no_build)  # rejected before any work
    with pytest.raises(ValueError, match=named):
        online.run_online(**arguments)


def test_run_online_takes_matching_gait_params_and_pattern(monkeypatch):
    """The CLI passes both: a pattern built from the same gait is not a disagreement."""
    import drake_estop.physics.online as online

    built = {}

    def stop_after_build(pattern, *args, **kwargs):
        built["pattern"] = pattern
        raise RuntimeError("stop here")

    monkeypatch.setattr(online, "build_online_diagram", stop_after_build)
    gait = GaitParameters(step_length=0.25)
    pattern = NominalPattern(gait)
    with pytest.raises(RuntimeError, match="stop here"):
        online.run_online(gait_params=gait, pattern=pattern, estop_time=3.4)
    assert built["pattern"] is pattern


def test_online_simulator_starts_the_robot_in_its_pose_with_the_model_errors_in_the_simulated_plant_only():
    handles = build_online_diagram(NominalPattern(), controller_stop_parameters(), None)
    plant = handles.plant
    simulator = online_simulator(handles, Perturbations(mass_scale=1.1))
    plant_context = plant.GetMyContextFromRoot(simulator.get_context())
    assert np.array_equal(plant.GetPositions(plant_context), handles.initial_q)
    nominal = plant.CalcTotalMass(plant.CreateDefaultContext())
    assert plant.CalcTotalMass(plant_context) == pytest.approx(1.1 * nominal)  # the simulated robot, x1.1
    assert simulator.get_context().get_time() == 0.0
    other = build_online_diagram(NominalPattern(), controller_stop_parameters(), None)
    plain = online_simulator(other)  # without perturbations: the nominal masses
    assert other.plant.CalcTotalMass(other.plant.GetMyContextFromRoot(plain.get_context())) == pytest.approx(nominal)


def test_the_controller_options_default_to_the_stop_planner_systems_own():
    """The planner's settings left at their defaults change nothing: StopPlannerConfig()."""
    from drake_estop.systems.decision import StopPlannerConfig

    assert ControllerOptions().planner == StopPlannerConfig()


def test_the_online_controller_builds_the_features_it_is_given(monkeypatch):
    """ControllerOptions to the diagram: the planner features reach StopPlannerSystem, true_state the
    estimator, and foot_compliance / swing_tilt None leave those systems out."""
    import drake_estop.physics.online as online
    from drake_estop.systems.decision import StopPlannerConfig

    seen = {}

    def spy(name):
        original = getattr(online, name)

        def recorded(*args, **kwargs):
            seen[name] = kwargs
            return original(*args, **kwargs)
        return recorded

    for name in ("add_stop_controller", "add_state_estimation"):
        monkeypatch.setattr(online, name, spy(name))
    planner = StopPlannerConfig(recovery_step=False, foothold_replan=True, max_replan_solves=None,
                                replan_threshold=0.06, relanded_footholds=False)
    controller = ControllerOptions(true_state=True, foot_compliance=None, swing_tilt=None, planner=planner)
    handles = build_online_diagram(NominalPattern(), controller_stop_parameters(), None, controller=controller)
    assert seen["add_stop_controller"]["config"] is planner
    assert seen["add_state_estimation"]["true_state"] is True
    assert handles.compliance is None and handles.swing_tilt is None
    assert not handles.diagram.HasSubsystemNamed("foothold_monitor")  # nobody would read it
    assert "ankle_offsets" not in handles.loggers and "swing_tilt" not in handles.loggers
    default = build_online_diagram(NominalPattern(), controller_stop_parameters(), None)
    assert default.compliance is not None and default.swing_tilt is not None
    monitor = default.diagram.GetSubsystemByName("foothold_monitor")
    assert default.planner.relanded_port.HasValue(default.planner.GetMyContextFromRoot(
        default.diagram.CreateDefaultContext())) and monitor.relanded_port.get_name() == "relanded"
    assert seen["add_state_estimation"]["true_state"] is False
    assert seen["add_stop_controller"]["config"] == StopPlannerConfig()


@pytest.mark.slow
def test_every_tick_of_the_online_paper_stop_is_capturable(paper_stop):
    """Unpushed, the measured state stays capturable on every tick of the run, and the summary reports the
    signal's tick."""
    capture = paper_stop.online["capture"]
    ticks = np.isfinite(capture[:, 0])
    assert np.count_nonzero(ticks) >= round(paper_stop.times[-1] / 0.005) - 2
    assert np.all(capture[ticks, 0] >= 0)
    summary = paper_stop.online["capturability"]
    assert summary["steps"] >= 0 and summary["margin"] >= 0.0
    assert summary["worst"]["margin"] == pytest.approx(np.nanmin(capture[int(round(3.4 / 0.005)):, 1]))
