"""Command line: ``drake-estop simulate`` (walk, latch the stop, log and summarise), ``sweep`` and ``campaign``."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import typing
from dataclasses import replace
from pathlib import Path

from drake_estop.physics.controller_options import CONTROLLER_KINDS
from drake_estop.physics.perturbations import Perturbations, add_perturbation_arguments, perturbations_from_args
from drake_estop.planning.gait import MAX_TURN_DEG, GaitParameters, NominalPattern, load_footsteps
from drake_estop.planning.plan import OBJECTIVES
from drake_estop.planning.planner import InfeasibleStop, StopParameters, plan_stop, warm_up
from drake_estop.planning.rollout import rollout, stop_metrics, write_log, write_summary
from drake_estop.robots.parameters import as_robot, com_height_range
from drake_estop.scenario import Scenario, dump_scenario, load_scenario

# -- option values: argparse ``type=`` functions; a bad value exits with status 2 and argparse
# names the option ("argument --crouch-depth: ...")

def number(*, low=None, high=None, low_open=False, high_open=False, integer=False, unit=""):
    """An argparse ``type=`` that parses a finite number inside [low, high] (ends open if asked)."""
    def parse(text):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{'a whole number' if integer else 'a number'} is needed, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text}")
        too_low = low is not None and (value < low or (low_open and value == low))
        too_high = high is not None and (value > high or (high_open and value == high))
        if too_low or too_high:
            left = "(-inf" if low is None else f"{'(' if low_open else '['}{low:g}"
            right = "inf)" if high is None else f"{high:g}{')' if high_open else ']'}"
            raise argparse.ArgumentTypeError(f"must be in {left}, {right}{unit}, got {text}")
        return value
    parse.__name__ = "integer" if integer else "number"
    return parse


positive_float = number(low=0.0, low_open=True)
non_negative_float = number(low=0.0)
finite_float = number()
port_number = number(low=1, high=65535, integer=True)


def _add_scenario_options(p):
    s = p.add_argument_group("scenario (YAML; the options below override it)")
    s.add_argument("--scenario-file", metavar="FILE.yaml",
                   help="start from this scenario (drake_estop.scenario.Scenario: gait, stop, estop_time, "
                        "simulation, controller, plant, perturbations, after_halt; see --print-scenario); the "
                        "online controller's features are set in its controller section, e.g. "
                        "'controller: {foot_compliance: null, planner: {recovery_step: false}}' "
                        "(drake_estop.physics.controller_options)")
    s.add_argument("--scenario-text", metavar="YAML", help="the same, inline, e.g. '{gait: {step_length: 0.2}}'")
    s.add_argument("--print-scenario", action="store_true",
                   help="print the effective scenario as YAML (every field) and exit")
    s.add_argument("--robot", metavar="NAME|FILE.yaml", default=None,
                   help="the humanoid: default (the HRP-2-class model), g1 (Unitree G1), talos (PAL TALOS; both "
                        "need pip install -e '.[robots]') or a robot description file (drake_estop.robots); the "
                        "gait and stop defaults below become its own (default: the scenario's robot, "
                        "%(default)s: default)")


def _add_gait_and_stop(p, scenario: Scenario, *, estop=True):
    """Gait and stop options shared by ``simulate`` and ``sweep``; their defaults come from ``scenario``."""
    _add_scenario_options(p)
    _GAIT, _STOP = scenario.gait, scenario.stop
    g = p.add_argument_group("gait (paper Section V defaults)")
    g.add_argument("--step-length", type=non_negative_float, default=_GAIT.step_length,
                   help="nominal step length [m] (default %(default)s)")
    g.add_argument("--step-time", type=positive_float, default=_GAIT.step_time,
                   help="nominal step cycle, single + double support [s] (default %(default)s)")
    g.add_argument("--step-width", type=positive_float, default=_GAIT.step_width,
                   help="lateral distance between the ankles [m] (default %(default)s)")
    g.add_argument("--double-support-ratio", type=number(low=0.0, high=1.0, low_open=True, high_open=True),
                   default=_GAIT.double_support_ratio,
                   help="share of the step cycle in double support (default %(default)s)")
    g.add_argument("--com-height", default=_GAIT.com_height, type=positive_float,
                   help="COG height of the LIPM [m], above the lowest the robot's legs reach and at most their "
                        "straight-leg height (default %(default)s: the robot's walking height, HRP-2's 0.814 for "
                        "the default robot)")
    g.add_argument("--num-steps", type=number(low=2, integer=True), default=_GAIT.num_steps,
                   help="steps of the nominal walk, the last one closing the feet (default %(default)s)")
    g.add_argument("--turn", type=number(low=-MAX_TURN_DEG, high=MAX_TURN_DEG, unit=" deg"), default=_GAIT.turn,
                   metavar="DEG", help=f"heading change per step [deg], positive to the left: walk on an arc "
                                       f"(|DEG| <= {MAX_TURN_DEG:g}; default %(default)s)")
    g.add_argument("--side-step", type=finite_float, default=_GAIT.side_step, metavar="M",
                   help="side step [m], positive to the left: the leading foot steps out by M, the trailing "
                        "one closes the stance, combined with --step-length (pure side-stepping: "
                        "--step-length 0; default %(default)s)")
    g.add_argument("--footsteps", metavar="FILE.csv", default=None,
                   help="explicit footsteps: CSV with columns side, x, y [m], yaw [rad] and an optional "
                        "duration [s], one row per step from the standing stance (replaces --step-length, "
                        "--turn, --side-step and --num-steps)")
    s = p.add_argument_group("stop")
    if estop:
        s.add_argument("--estop-time", type=non_negative_float, default=scenario.estop_time,
                       help="time of the stop signal [s]; latched at the next servo tick (default %(default)s)")
    s.add_argument("--servo-period", default=_STOP.servo_period,
                   type=number(low=0.0, high=_STOP.min_transition_time, low_open=True, unit=" s"),
                   help="servo / control period [s]; phase boundaries fall on its ticks (default %(default)s)")
    s.add_argument("--no-crouch", action="store_true", default=not _STOP.crouch,
                   help="keep the COG height constant (no IV.A crouch)")
    s.add_argument("--crouch-depth", type=non_negative_float, default=_STOP.crouch_depth,
                   help="COG lowering during the stop [m] (default %(default)s)")
    s.add_argument("--a-ss", type=positive_float, default=_STOP.a_ss, help="J_ss swing-speed weight (eq. 24)")
    s.add_argument("--b-ss", type=positive_float, default=_STOP.b_ss, help="J_ss double-support-time weight (eq. 24)")
    s.add_argument("--a-ds", type=positive_float, default=_STOP.a_ds,
                   help="J_ds ZMP-displacement weight (eq. 30; --physics: the robot's own if it gives one)")
    s.add_argument("--b-ds", type=positive_float, default=_STOP.b_ds, help="J_ds double-support-time weight (eq. 30)")
    s.add_argument("--max-step-length", type=positive_float, default=_STOP.max_step_length,
                   help="longest landing step from the support ankle [m] (default %(default)s)")
    s.add_argument("--max-swing-speed", type=positive_float, default=_STOP.max_swing_speed,
                   help="mean swing-ankle speed limit to the landing point [m/s] (default %(default)s)")
    s.add_argument("--quantisation", choices=("resolve", "round"), default=_STOP.quantisation,
                   help="'resolve' re-solves the ZMP after snapping phase times to ticks (default); "
                        "'round' only rounds the times, as in the paper")
    s.add_argument("--objective", choices=OBJECTIVES, default=_STOP.objective,
                   help="'paper': J_ss / J_ds (eq. 24, 30), slowdown and halt (default); 'time': the soonest "
                        "rest at the feet's midpoint within the same limits (drake_estop.planning.brake)")
    _add_field_options(p, scenario)


#: fields set by the curated options above (or only in a scenario file: tuples, the sole)
_CURATED = {"crouch"}
_OPTION_TYPES = {float: finite_float, int: number(integer=True), str: str}


def _scalar_fields(cls):
    hints = typing.get_type_hints(cls)
    return [(f.name, hints[f.name]) for f in dataclasses.fields(cls) if hints[f.name] in _OPTION_TYPES]


def _add_field_options(p, scenario: Scenario):
    """One option per remaining scalar field of GaitParameters and StopParameters, generated from the
    dataclasses (``--lift-height``, ``--zmp-margin``, ...); the classes validate the values."""
    curated = _CURATED | {action.dest for action in p._actions}
    group = p.add_argument_group("every other gait / stop parameter (validated by GaitParameters / StopParameters)")
    for cls, defaults in ((GaitParameters, scenario.gait), (StopParameters, scenario.stop)):
        for name, kind in _scalar_fields(cls):
            if name not in curated:
                group.add_argument(f"--{name.replace('_', '-')}", type=_OPTION_TYPES[kind],
                                   default=getattr(defaults, name),
                                   help=f"{cls.__name__}.{name} (default %(default)s)")


def _add_simulate(sub, scenario: Scenario):
    p = sub.add_parser(
        "simulate",
        help="walk the nominal pattern, latch an emergency stop, write a log and a summary",
        description="Walk the nominal pattern, latch the emergency stop at --estop-time (sampled at the "
                    "next servo tick) and plan the four-phase stop (Morisawa et al. 2005). Runs the Drake "
                    "diagram (planner, whole-body IK, humanoid) unless --kinematic; --physics simulates the "
                    "humanoid with contact. Writes a per-tick CSV log and a JSON summary.",
    )
    _add_gait_and_stop(p, scenario)
    d = p.add_argument_group("Drake diagram (default) and Meshcat")
    d.add_argument("--kinematic", action="store_true", default=scenario.simulation == "kinematic",
                   help="plan and roll out the reference only (numpy), without the Drake diagram / IK")
    d.add_argument("--physics", action="store_true", default=scenario.simulation == "physics",
                   help="simulate the humanoid with contact (discrete SAP plant, PD servos tracking the "
                        "IK joint angles) under the online controller and check the success criteria; "
                        "adds cop_x, cop_y, pelvis_z, com_meas_*, com_est_* to the log")
    d.add_argument("--controller", choices=CONTROLLER_KINDS, default=scenario.controller.kind,
                   help="with --physics: 'online' (default) plans and re-plans from the estimated state "
                        "tick by tick; 'offline-filter' computes the whole joint reference with the ZMP "
                        "preview filter at the signal (for comparison; not a real-time controller); the "
                        "scenario's controller.kind")
    d.add_argument("--true-state", action="store_true", default=scenario.controller.true_state,
                   help="with --physics: feed the controller the true COG instead of the state estimate (the "
                        "scenario's controller.true_state)")
    add_perturbation_arguments(p, scenario.perturbations)
    d.add_argument("--html", metavar="FILE.html", help="write a self-contained Meshcat replay (opens offline)")
    d.add_argument("--meshcat", action="store_true",
                   help="show the run live in Meshcat (prints the URL; runs in real time; the "
                        "'Emergency stop' button stops the robot)")
    d.add_argument("--meshcat-port", type=port_number, default=None, help="Meshcat port (default: a free one)")
    d.add_argument("--meshcat-host", default=None, metavar="HOST",
                   help="interface Meshcat listens on (default localhost: this machine only); '*' or an "
                        "address opens the live view and its stop button to the network (warns)")
    d.add_argument("--button-only", action="store_true",
                   help="with --meshcat: no scheduled stop, only the Meshcat button stops the walk")
    o = p.add_argument_group("output")
    o.add_argument("--log", metavar="FILE.csv", help="per-servo-tick log (runs >= 1 s past the halt)")
    o.add_argument("--summary", metavar="FILE.json", help="JSON summary of the stop")
    o.add_argument("--after-halt", type=number(low=1.0, unit=" s"), default=scenario.after_halt,
                   help="seconds logged after the end of the halt (default %(default)s, at least 1)")
    p.set_defaults(func=_simulate, scenario=scenario)


def _parameters(args):
    args.robot_description = as_robot(args.scenario.robot)
    gait = replace(args.scenario.gait, **{name: getattr(args, name) for name, _ in _scalar_fields(GaitParameters)})
    stop = replace(args.scenario.stop, crouch=not args.no_crouch,
                   **{name: getattr(args, name) for name, _ in _scalar_fields(StopParameters) if name != "crouch"})
    if getattr(args, "footsteps", None):
        try:
            gait = replace(gait, footsteps=load_footsteps(args.footsteps))
        except OSError as error:
            raise ValueError(f"footsteps: cannot read {args.footsteps} ({error.strerror})") from None
    if gait.step_length > stop.max_step_length:
        raise ValueError(f"step_length {gait.step_length} m exceeds max_step_length {stop.max_step_length} m")
    if gait.step_length < 0:
        raise ValueError(f"step_length must be >= 0, got {gait.step_length}")
    if args.after_halt < 1.0 or not math.isfinite(args.after_halt):
        raise ValueError(f"after_halt must be at least 1 s, got {args.after_halt}")
    lowest, highest = com_height_range(args.robot_description)
    if not lowest < gait.com_height <= highest:
        raise ValueError(f"com_height must be in ({lowest:g}, {highest:g}] m for robot "
                         f"{args.robot_description.name!r} (knees at their limit, straight legs), "
                         f"got {gait.com_height:g}")
    if not args.no_crouch and gait.com_height - stop.crouch_depth < lowest:
        raise ValueError(f"crouch_depth {stop.crouch_depth} m takes the COG from {gait.com_height} m below "
                         f"{lowest} m, the lowest the legs of robot {args.robot_description.name!r} reach "
                         "(knees at their limit)")
    if getattr(args, "meshcat_port", None) is not None and not args.meshcat:
        raise ValueError("meshcat_port needs --meshcat")
    if getattr(args, "meshcat_host", None) is not None and not args.meshcat:
        raise ValueError("meshcat_host needs --meshcat")
    return gait, stop


def _controller(args):
    """The scenario's controller section with the command line's ``--controller`` and ``--true-state``."""
    return replace(args.scenario.controller, kind=args.controller, true_state=args.true_state)


def _effective_scenario(args, gait, stop) -> Scenario:
    """The scenario this command line runs (the file's, with the options applied)."""
    simulation = "physics" if args.physics else "kinematic" if args.kinematic else "diagram"
    return replace(args.scenario, gait=gait, stop=stop, estop_time=None if args.button_only else args.estop_time,
                   simulation=simulation, controller=_controller(args), perturbations=perturbations_from_args(args),
                   after_halt=args.after_halt)


def _online_only_settings(controller, perturbations) -> list:
    """The settings given that only the online controller's physics run takes: the perturbations and the
    controller section's fields off their defaults, by scenario name."""
    return ((["perturbations"] if perturbations != Perturbations() else [])
            + [f"controller.{name}" for name in controller.changed()])


def _simulate(args) -> int:
    gait, stop = _parameters(args)
    if args.print_scenario:
        print(dump_scenario(_effective_scenario(args, gait, stop)), end="")
        return 0
    pattern = NominalPattern(gait)
    estop_time = None if args.button_only else args.estop_time
    if args.button_only and not args.meshcat:
        raise ValueError("button_only needs --meshcat (a person must be able to press the button)")
    if estop_time is not None and not (math.isfinite(estop_time) and 0.0 <= estop_time <= pattern.end_time):
        raise ValueError(f"estop_time {estop_time} s is outside the run [0, {pattern.end_time:.3f}] s")
    if args.physics and (args.kinematic or args.html or args.meshcat or estop_time is None):
        raise ValueError("physics runs take a scheduled --estop-time and no --kinematic/--html/--meshcat")
    perturbations = perturbations_from_args(args)
    controller = _controller(args)
    online_only = _online_only_settings(controller, perturbations)
    physics_only = online_only + (["controller.kind"] if controller.kind != "online" else [])
    if not args.physics and physics_only:
        raise ValueError(f"{' and '.join(physics_only)}: only with --physics")
    if controller.kind == "offline-filter" and online_only:
        raise ValueError(f"{' and '.join(online_only)}: only with controller.kind online (--controller online)")
    if args.physics:
        args.after_halt = max(args.after_halt, 2.5)  # the rest criterion looks 2 s past the halt
        plan, extra, diagram_summary = _run_physics(args, gait, stop, pattern, estop_time, perturbations,
                                                     controller)
    elif args.kinematic:
        if args.html or args.meshcat:
            raise ValueError("--html and --meshcat need the Drake diagram (drop --kinematic)")
        warm_up(pattern, stop)  # the compiled solver loads here, so the plan time below is real
        plan = plan_stop(pattern, estop_time, stop)
        extra, diagram_summary = {}, {}
    else:
        plan, extra, diagram_summary = _run_diagram(args, gait, stop, estop_time)
        if plan is None:
            print("walk ended without a stop signal")
            return 0
    data = rollout(plan, after_halt=args.after_halt)
    summary = {"robot": args.robot_description.name, **plan.summary()}
    summary["metrics"] = stop_metrics(plan, data)
    summary.update(diagram_summary)
    if args.log:
        write_log(args.log, data, {name: _fit(values, len(data.times)) for name, values in extra.items()})
    if args.summary:
        write_summary(args.summary, summary)
    times = summary["phase_times"]
    print(f"stop signal {plan.signal_time:.3f} s in {plan.support} support -> {plan.case}; "
          f"landing {times['landing_end']:.3f}, transition {times['transition_end']:.3f}, "
          f"slowdown {times['slowdown_end']:.3f}, halt {times['halt_end']:.3f} s; "
          f"plan {plan.compute_time * 1e3:.2f} ms{_plan_time_note(args, summary)}, "
          f"{plan.newton_iterations} Newton iterations")
    print(_steps_line(summary["steps"]))
    if "ik" in summary:
        ik = summary["ik"]
        print(f"whole-body IK: COG error max {ik['ik_com_err_max_m'] * 1e3:.3f} mm, foot error max "
              f"{ik['ik_foot_err_max_m'] * 1e3:.3f} mm, ticks over bounds {ik['ik_ticks_over_bounds']}, "
              f"joint-velocity-limit violations {ik['velocity_limit_violations']}")
        if ik.get("stop_multibody_zmp_margin_min_m") is not None:  # the run's least is then one too
            print(f"whole-body ZMP (the limbs' momentum included): least margin in the soles "
                  f"{ik['multibody_zmp_margin_min_m'] * 1e3:.1f} mm, in the stop "
                  f"{ik['stop_multibody_zmp_margin_min_m'] * 1e3:.1f} mm (below 0: outside the feet)")
    if args.html:
        print(f"replay written to {args.html} (open it in a browser; works offline)")
    if "physics" in summary:
        physics = summary["physics"]
        failed = [name for name, ok in physics["criteria"].items() if not ok]
        print(f"physics: {'all criteria met' if not failed else 'FAILED ' + ', '.join(failed)}; "
              f"measured COG at rest {physics['numbers']['rest_after_halt_s']:.2f} s after the planned halt, "
              f"{physics['numbers']['final_cog_offset_m'] * 1e3:.1f} mm from the feet's midpoint; "
              f"real-time factor {physics['numbers']['realtime_factor']:.2f}")
        if "tick_compute" in summary:
            tick, cpu = summary["tick_compute"], summary["tick_compute_cpu"]
            print(f"online controller: {summary['replans']} re-plans ({summary['replan_failures']} found no "
                  f"stop), work per tick median {tick['median'] * 1e3:.2f} ms, p99 {tick['p99'] * 1e3:.2f} ms, "
                  f"max {tick['max'] * 1e3:.2f} ms (CPU time: max {cpu['max'] * 1e3:.2f} ms); "
                  f"ticks over a joint-velocity limit {summary['joint_velocity_violations']}")
            if summary.get("latch_fallback"):
                print("  no stop from the measured state at the signal: planned from the reference "
                      f"(then re-planned from the measured state): {summary['latch_fallback']}")
            print("  CPU per tick by block (mean): " + _block_times(summary["tick_compute_by_block"], 5))
            worst = summary["tick_compute_slowest"][0]
            print(f"  slowest tick (CPU) at {worst['t']:.3f} s, {worst['total'] * 1e3:.2f} ms: "
                  + _block_times(worst["blocks"], 3))
        return 0 if not failed else 1
    return 0


def _steps_line(steps: list) -> str:
    """``"steps after the signal: 2 (3.510 s right foot: walk; ...)"``: each landing and why."""
    listed = "; ".join(f"{step['time']:.3f} s {step['foot']} foot: {step['kind']}" for step in steps)
    return f"steps after the signal: {len(steps)}" + (f" ({listed})" if steps else "")


def _block_times(blocks: dict, count: int) -> str:
    """``"label 0.12 ms, ..."``: the first ``count`` of ``{label: seconds}`` (largest first)."""
    return ", ".join(f"{label} {seconds * 1e3:.2f} ms" for label, seconds in list(blocks.items())[:count])


def _fit(values, n):
    """``values`` cut or NaN-padded to ``n`` log rows."""
    import numpy as np

    values = np.asarray(values, float)[:n]
    return np.concatenate([values, np.full(n - len(values), np.nan)]) if len(values) < n else values


def _run_physics(args, gait, stop, pattern, estop_time, perturbations, controller):
    """Physics run; returns the plan, per-tick measured columns and the summary entry."""
    columns, online = {}, {}
    if controller.kind == "online":
        from drake_estop.physics.online import controller_stop_parameters, run_online

        stop = controller_stop_parameters(stop, braked_landing=controller.braked_landing,
                                          robot=args.robot_description)
        result = run_online(gait, stop, estop_time, after_halt=args.after_halt, pattern=pattern,
                            perturbations=perturbations, physics=_physics_parameters(args.scenario),
                            controller=controller, robot=args.robot_description)
        online = {key: result.online[key] for key in
                  ("tick_compute", "tick_compute_cpu", "tick_compute_by_block", "tick_compute_slowest", "replans",
                   "replan_failures", "latch_fallback",
                   "joint_velocity_violations", "cpu_realtime_factor", "ankle_offset_max", "swing_tilt_max",
                   "hip_strategy_bow_max", "touchdown_depth_max", "capturability", "modes")}
        online["perturbations"] = perturbations.summary()
        com_est = result.online["com_est"]
        columns.update({"com_est_x": com_est[:, 0], "com_est_y": com_est[:, 1], "com_est_z": com_est[:, 2],
                        "one_step_feasible": result.online["one_step_feasible"],
                        # the stop's mode after the tick (systems.decision.StopMode) and the landings left
                        "mode": result.online["mode"][:, 0], "steps_left": result.online["mode"][:, 1],
                        # -1 where no N <= 3 steps capture the measured state (planning.capturability)
                        "capture_steps": result.online["capture"][:, 0],
                        "capture_margin": result.online["capture"][:, 1]})
    else:
        from drake_estop.physics.offline import run_physics

        result = run_physics(gait, stop, estop_time, after_halt=args.after_halt, pattern=pattern,
                             physics=_physics_parameters(args.scenario), robot=args.robot_description)
    columns.update({"cop_x": result.cop_x, "cop_y": result.cop_y, "pelvis_z": result.pelvis_z,
                    "com_meas_x": result.com_meas_x, "com_meas_y": result.com_meas_y,
                    "com_meas_z": result.com_meas_z, "torso_tilt": result.torso_tilt})
    summary = {"controller": controller.kind, "success": result.success,
               "criteria": {k: bool(v) for k, v in result.criteria.items()}, **online,
               "physics": {"criteria": {k: bool(v) for k, v in result.criteria.items()},
                           "success": result.success, "numbers": result.numbers(), "cop_exit": result.cop_exit()}}
    return result.plan, columns, summary


def _physics_parameters(scenario: Scenario):
    """The physics settings of the scenario's plant config (time step, contact model)."""
    from drake_estop.physics.plant import PhysicsParameters

    contact = "point" if scenario.plant.contact_model == "point" else "hydroelastic"
    return PhysicsParameters(time_step=scenario.plant.time_step, contact=contact)


def _run_diagram(args, gait, stop, estop_time):
    """Run the Drake diagram; returns the plan, per-tick IK columns and summary entries."""
    import warnings

    from drake_estop.systems.diagram import simulate_diagram
    from drake_estop.systems.visualization import make_meshcat

    meshcat = None
    if args.meshcat:
        meshcat = make_meshcat(args.meshcat_port, host=args.meshcat_host or "localhost")
        print(f"Meshcat: {meshcat.web_url()}  (press 'Emergency stop' in the controls to stop the robot)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # IK misses are reported in the summary below
        result = simulate_diagram(gait, stop, estop_time, html=args.html, meshcat=meshcat,
                                  after_halt=args.after_halt, robot=args.robot_description)
    summary = {
        "ik": result.error_summary(),
        "realtime_factor": result.realtime_factor,
        "plan_wall_time_in_diagram_s": result.plan_wall_time,
        "plan_compute_time_s": None if result.plan is None else result.plan.compute_time,
    }
    return result.plan, result.columns(), summary


def _plan_time_note(args, summary) -> str:
    """Where the plan time was measured: a single cold plan (``--kinematic``), the diagram's plan made on
    the walking tick before the latch and the latch's own time; in physics the controller's work per tick
    is reported below."""
    if args.kinematic:
        return " (one plan, cold)"
    latch = summary.get("plan_wall_time_in_diagram_s")
    return "" if latch is None else f" (made while walking; the latch {latch * 1e3:.2f} ms)"


def _add_sweep(sub, scenario: Scenario):
    p = sub.add_parser(
        "sweep",
        help="physics runs for stop signals over one stride; writes the stop map (CSV + figure)",
        description="Stop signals every --every seconds over one full stride of the nominal walk (the "
                    "third step: single then double support), each simulated in physics with contact; "
                    "writes a table and the stop map (case, step length, time to rest, COG travel, "
                    "success per signal time).",
    )
    _add_gait_and_stop(p, scenario, estop=False)
    o = p.add_argument_group("sweep")
    o.add_argument("--every", type=positive_float, default=0.02, help="signal spacing [s] (default %(default)s)")
    o.add_argument("--csv", default="out/sweep.csv", help="table (default %(default)s)")
    o.add_argument("--png", default="out/stop_map.png", help="stop map figure (default %(default)s)")
    o.add_argument("--no-progress", action="store_true", help="no progress bar")
    o.add_argument("--controller", choices=CONTROLLER_KINDS, default=scenario.controller.kind,
                   help="the physics controller of every run (default %(default)s; see simulate --help); the "
                        "online controller's features come from the scenario's controller section")
    _add_executor_options(p)
    p.set_defaults(func=_sweep, after_halt=2.5, scenario=scenario)


def _add_executor_options(p):
    """``--workers`` / ``--scheduler``: the Dask executor of ``sweep`` and ``campaign``."""
    e = p.add_argument_group("execution (Dask)").add_mutually_exclusive_group()
    e.add_argument("--workers", type=number(low=1, integer=True), default=None, metavar="K",
                   help="worker processes of a local Dask cluster, one thread each (default: every core)")
    e.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://host:8786 (exit 2 if unreachable in 3 s)")


def _sweep(args) -> int:
    import functools

    from drake_estop.campaign.executor import map_tasks
    from drake_estop.physics.criteria import CRITERIA
    from drake_estop.physics.sweep import sweep, write_sweep

    gait, stop = _parameters(args)
    controller = replace(args.scenario.controller, kind=args.controller)
    if args.print_scenario:
        print(dump_scenario(replace(args.scenario, gait=gait, stop=stop, simulation="physics",
                                    controller=controller)), end="")
        return 0
    online_only = _online_only_settings(controller, Perturbations())
    if controller.kind == "offline-filter" and online_only:
        raise ValueError(f"{' and '.join(online_only)}: only with controller.kind online (--controller online)")
    if not (math.isfinite(args.every) and args.every > 0):
        raise ValueError(f"every must be a positive number of seconds, got {args.every}")
    start, end = NominalPattern(gait).stride()
    if args.every > end - start:
        raise ValueError(f"every {args.every} s is longer than the stride ({end - start:.3f} s)")
    run = None
    if controller.kind == "online":
        from drake_estop.physics.online import controller_stop_parameters, run_online

        stop = controller_stop_parameters(stop, braked_landing=controller.braked_landing,
                                          robot=args.robot_description)
        run = functools.partial(run_online, controller=controller)
    executor = functools.partial(map_tasks, workers=args.workers, scheduler=args.scheduler,
                                 progress=not args.no_progress, desc="physics sweep")
    table = sweep(gait, stop, every=args.every, start=start, duration=end - start,
                  progress=not args.no_progress, run=run, executor=executor, robot=args.robot_description)
    write_sweep(table, args.csv, args.png)
    wins = sum(bool(row.get("success")) for row in table)
    failed = [row for row in table if not row.get("success")]
    print(f"{wins}/{len(table)} stops met every criterion ({100 * wins / len(table):.0f} %); "
          f"table {args.csv}, stop map {args.png}")
    for row in failed:
        reason = row.get("error") or ", ".join(k for k in CRITERIA if row.get(k) is False)
        print(f"  FAILED at {row['signal_time']:.3f} s: {reason}")
    if failed:
        print(f"sweep FAILED: {len(failed)} stop(s) missed a criterion, signal times "
              + ", ".join(f"{row['signal_time']:.3f}" for row in failed) + " s", file=sys.stderr)
        return 1
    return 0


def _add_campaign(sub):
    p = sub.add_parser(
        "campaign",
        help="randomised physics stops (signal, gait, push, model error, friction, latency, noise) on Dask; "
             "resumable; writes a report",
        description="Run N physics stops with the online controller, each with parameters sampled from the "
                    "config's ranges by its own seed, on a local Dask cluster or an existing one. Every "
                    "finished run is written at once to DIR/results/; running the same command again resumes "
                    "(skips the seeds already done). Writes DIR/report.html (push-recovery map, success against "
                    "the signal phase and the model error, every failure with the simulate command that "
                    "reproduces it). Exit status 0 once every run has a row (failed runs included), 2 on bad "
                    "input (nothing written).",
    )
    p.add_argument("--runs", type=number(low=1, integer=True), required=True, metavar="N", help="number of runs")
    p.add_argument("--seed", type=number(low=0, integer=True), default=0, metavar="S",
                   help="campaign seed; run i's seed derives from (S, i) (default %(default)s)")
    p.add_argument("--out", required=True, metavar="DIR", help="result folder (created; reused to resume)")
    p.add_argument("--config", metavar="FILE.yaml",
                   help="ranges overriding the shipped default (drake_estop/campaign/default.yaml) key by key")
    p.add_argument("--robot", default="default", metavar="NAME|FILE.yaml",
                   help="the robot of every run (default %(default)s); without --config the default ranges are "
                        "scaled to it: the gait by its own, the pushes by its mass")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_executor_options(p)
    p.set_defaults(func=_campaign)


def _campaign(args) -> int:
    from drake_estop.campaign.config import load_config, scaled_to_robot
    from drake_estop.campaign.runner import CampaignInterrupted, run_campaign
    from drake_estop.robots import as_robot

    robot = as_robot(args.robot)  # a bad name or file exits 2, naming robot
    config = load_config(args.config)
    if args.config is None:
        config = scaled_to_robot(config, args.robot)
    try:
        table = run_campaign(runs=args.runs, seed=args.seed, out=args.out, config=config, workers=args.workers,
                             scheduler=args.scheduler, progress=not args.no_progress,
                             robot="default" if robot.name == "default" else args.robot)
    except CampaignInterrupted as stop:
        print(f"campaign {stop}; report {args.out}/report.html", file=sys.stderr)
        return 130
    outcomes = table.column("outcome").to_pylist()
    wins = outcomes.count("success")
    print(f"{wins}/{len(outcomes)} runs met every criterion ({100 * wins / len(outcomes):.1f} %); "
          f"{outcomes.count('failure')} failed a criterion, {outcomes.count('error')} errors, "
          f"{outcomes.count('timeout')} timeouts; report {args.out}/report.html")
    return 0


def build_parser(scenario: Scenario | None = None) -> argparse.ArgumentParser:
    """The ``drake-estop`` parser; option defaults from ``scenario`` (default: ``Scenario()``)."""
    scenario = scenario or Scenario()
    parser = argparse.ArgumentParser(
        prog="drake-estop",
        description="Emergency stop for walking humanoids (Morisawa et al., IROS 2005) on Drake.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    _add_simulate(sub, scenario)
    _add_sweep(sub, scenario)
    _add_campaign(sub)
    return parser


def _scenario_from(argv) -> Scenario:
    """The scenario named by --scenario-file / --scenario-text in ``argv`` (default ``Scenario()``), for the
    robot of --robot if given (its gait and stop defaults; see :func:`drake_estop.scenario.load_scenario`)."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--scenario-file")
    pre.add_argument("--scenario-text")
    pre.add_argument("--robot")
    known, _ = pre.parse_known_args(argv)
    if known.scenario_file is not None and known.scenario_text is not None:
        raise ValueError("give --scenario-file or --scenario-text, not both")
    if known.scenario_file is not None:
        if not Path(known.scenario_file).is_file():
            raise FileNotFoundError(f"--scenario-file: no such file {known.scenario_file}")
        return load_scenario(filename=known.scenario_file, robot=known.robot)
    if known.scenario_text is not None:
        return load_scenario(text=known.scenario_text, robot=known.robot)
    return load_scenario(text="{}", robot=known.robot)


def main(argv=None) -> int:
    try:
        scenario = _scenario_from(sys.argv[1:] if argv is None else argv)
    except (ValueError, FileNotFoundError) as error:
        print(f"drake-estop: error: {error}", file=sys.stderr)
        return 2
    parser = build_parser(scenario)
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # argparse printed the usage and the bad option (status 2); --help: 0
        if stop.code == 2:
            return 2
        raise
    try:
        return args.func(args)
    except (ValueError, InfeasibleStop, FileNotFoundError, RuntimeError) as error:
        print(f"drake-estop: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
