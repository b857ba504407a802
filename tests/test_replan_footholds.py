"""StopPlannerSystem's re-plans on the measured soles (``measured_feet``): after the landing, a foot
measured off the plan (``foothold_replan``), a sole that re-lands off its foothold (``relanded_footholds``,
with the FootholdMonitor beside the planner)."""

import numpy as np
import pytest
from planner_helpers import DT, latched_stop_planner, monitored_stop_planner, moved_feet, replan_params, state_at
from pydrake.systems.analysis import Simulator

from drake_estop.systems.decision import StopPlannerConfig
from drake_estop.systems.stop_controller import StopPlannerSystem
from drake_estop.systems.stop_numerics import (
    SOLE_AWAY,
    SOLE_LIFTED,
    SOLE_RELANDED,
    SOLE_STANDING,
    foothold_loaded,
    next_sole_stage,
)


@pytest.fixture(scope="module")
def params():
    return replan_params()


def _landed_replan(pattern, params, feet_input, **kwargs):
    """StopPlannerSystem alone (FixValue inputs, Simulator.AdvanceTo): the stop latched at 3.4 s from the
    reference, no measurement until 20 ms after the landing, then a COG 5 cm/s faster than the plan's
    (past a 1 cm threshold) and ``feet_input`` on ``measured_feet``. Returns the planner, its context,
    the first plan and the re-plan tick."""
    planner, context, simulator, first = latched_stop_planner(pattern, params, landed_replan_threshold=0.01,
                                                              **kwargs)
    t = round((first.landing_time + 0.02) / DT) * DT
    simulator.AdvanceTo(t - DT / 2)
    assert planner.replans(context) == (0, 0)
    pos, vel, _ = state_at(first, t)
    planner.measured_com_port.FixValue(context, [*pos, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*(vel + np.array([0.05, 0.0])), 0.0])
    if feet_input is not None:
        planner.measured_feet_port.FixValue(context, feet_input(first))
    simulator.AdvanceTo(t + DT / 2)
    assert planner.replans(context) == (1, 0)
    return planner, context, first, t


def _feet_vector(plan, ticks=(40.0, 40.0)):
    feet = moved_feet(plan)
    return [*feet["left"], *feet["right"], *ticks]


def test_planner_replans_after_the_landing_on_the_measured_feet_and_blends_the_sole_targets(pattern, params):
    planner, context, first, t = _landed_replan(pattern, params, _feet_vector)
    feet = moved_feet(first)
    new = planner.plan(context)
    for side in feet:
        np.testing.assert_allclose(new.final_feet[side][:2], feet[side], atol=1e-12)
    # the sole targets start at the old command (a loaded foot's target must not step) and reach the
    # footholds at rest after blend_time
    for side in feet:
        port = planner.GetOutputPort(f"{side}_foot")
        np.testing.assert_allclose(port.Eval(context)[:2], first.feet(t)[side][:2], atol=1e-6)
    planner.measured_com_port.FixValue(context, [np.nan] * 3)  # no further re-plan
    Simulator(planner, context).AdvanceTo(t + 0.2 + DT / 2)
    assert planner.replans(context) == (1, 0)
    for side in feet:
        np.testing.assert_allclose(planner.GetOutputPort(f"{side}_foot").Eval(context)[:2], feet[side],
                                   atol=1e-9)


@pytest.mark.parametrize("feet_input, kwargs", [
    (None, {}),  # not connected
    (_feet_vector, {"measured_footholds": False}),
    (lambda plan: _feet_vector(plan, ticks=(1.0, 1.0)), {}),  # loaded one tick, under foothold_ticks
    (lambda plan: [np.nan] * 6, {}),
])
def test_planner_keeps_the_plans_feet_without_usable_footholds(pattern, params, feet_input, kwargs):
    planner, context, first, _ = _landed_replan(pattern, params, feet_input, **kwargs)
    new = planner.plan(context)
    for side in ("left", "right"):
        np.testing.assert_allclose(new.final_feet[side], first.final_feet[side], atol=1e-12)


@pytest.mark.parametrize("value", [0, -1, 1.5, True, float("nan")])
def test_planner_rejects_bad_foothold_ticks(pattern, params, value):
    with pytest.raises(ValueError, match="foothold_ticks"):
        StopPlannerSystem(pattern=pattern, params=params, config=StopPlannerConfig(foothold_ticks=value))


# -- a foot measured off the plan (foothold_replan) ----------------------------------------------------


def _measure_on_the_plan(planner, context, plan, t):
    """Fix the planner's measured COG (0.8 m high) and its velocity at ``plan``'s state at ``t``: the DCM
    on the plan."""
    pos, vel, _ = state_at(plan, t)
    planner.measured_com_port.FixValue(context, [*pos, 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])


def _on_the_plan_after_the_landing(pattern, params, **kwargs):
    """StopPlannerSystem alone: the stop latched at 3.4 s, advanced to just before the tick ``t`` 20 ms
    after the landing, with the measured COG the plan's there (the DCM on the plan). Returns the planner,
    its context, the simulator, the first plan and t."""
    planner, context, simulator, first = latched_stop_planner(pattern, params, **kwargs)
    t = round((first.landing_time + 0.02) / DT) * DT
    simulator.AdvanceTo(t - DT / 2)
    _measure_on_the_plan(planner, context, first, t)
    return planner, context, simulator, first, t


def _feet_at_the_plan(pattern, params, shift, **kwargs):
    """:func:`_on_the_plan_after_the_landing`, then at ``t`` the measured soles are the plan's feet moved by
    ``shift`` (side -> (dx, dy)), loaded 40 ticks. Returns the planner, its context, the simulator, the first
    plan, t and the measured feet."""
    planner, context, simulator, first, t = _on_the_plan_after_the_landing(pattern, params, **kwargs)
    feet = {side: first.final_feet[side] + np.asarray(shift.get(side, (0.0, 0.0))) for side in ("left", "right")}
    planner.measured_feet_port.FixValue(context, [*feet["left"], *feet["right"], 40.0, 40.0])
    simulator.AdvanceTo(t + DT / 2)
    return planner, context, simulator, first, t, feet


def test_a_foot_measured_off_the_plan_replans_on_the_measured_feet_each_time_it_moves(pattern, params):
    """With the DCM on the plan, a sole measured 1 cm from the plan's foot (more than foothold_tolerance)
    re-plans the stop on the measured feet (``foothold_replan``); a sole that slides on re-plans again, no
    sooner than the re-plan interval after the last, and one that stays where the plan stands does not."""
    planner, context, simulator, first, t, feet = _feet_at_the_plan(pattern, params, {"left": (0.0, -0.01)},
                                                                    foothold_replan=True)
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(t) and new.recovery_step is False
    for side in feet:
        np.testing.assert_allclose(new.final_feet[side][:2], feet[side], atol=1e-12)
    # standing where the re-plan put it: no re-plan over the next 0.1 s
    _measure_on_the_plan(planner, context, new, t + 0.1)
    simulator.AdvanceTo(t + 0.1 - DT / 2)
    assert planner.replans(context) == (1, 0) and planner.plan(context) is new
    # the foot slides on by another centimetre: a second re-plan stands on it, at the next tick
    slid = feet["left"] + [0.0, -0.01]
    planner.measured_feet_port.FixValue(context, [*slid, *feet["right"], 40.0, 40.0])
    simulator.AdvanceTo(t + 0.1 + DT / 2)
    assert planner.replans(context) == (2, 0)
    again = planner.plan(context)
    assert again.start_time == pytest.approx(t + 0.1)
    np.testing.assert_allclose(again.final_feet["left"][:2], slid, atol=1e-12)
    np.testing.assert_allclose(again.final_feet["right"][:2], feet["right"], atol=1e-12)


@pytest.mark.parametrize("shift, kwargs", [
    ({"left": (0.0, -0.003)}, {"foothold_replan": True}),  # within the 5 mm tolerance
    ({"left": (0.0, -0.01)}, {}),  # the foothold re-plan off (the default)
    ({"left": (0.0, -0.01)}, {"foothold_replan": True, "foothold_tolerance": 0.02}),  # a wider tolerance
])
def test_feet_within_the_tolerance_keep_the_plan(pattern, params, shift, kwargs):
    planner, context, _, first, _, _ = _feet_at_the_plan(pattern, params, shift, **kwargs)
    assert planner.replans(context) == (0, 0)
    assert planner.plan(context) is first


# -- the halt on the measured feet (halt_footholds) -----------------------------------------------------


def _in_the_halt(pattern, params, **kwargs):
    """StopPlannerSystem alone: the stop latched at 3.4 s, advanced to the tick ``t`` 0.1 s into the halt with
    the measured COG 2 cm behind the plan's (the DCM within the threshold) and the left sole measured 1 cm
    inside the plan's foot, both loaded 40 ticks. Returns the planner, its context, the simulator, the first
    plan, t and the measured feet."""
    planner, context, simulator, first = latched_stop_planner(pattern, params, **kwargs)
    t = round((first.slowdown_end + 0.1) / DT) * DT
    simulator.AdvanceTo(t - DT / 2)
    pos, vel, _ = state_at(first, t)
    planner.measured_com_port.FixValue(context, [pos[0] - 0.02, pos[1], 0.8])
    planner.measured_com_vel_port.FixValue(context, [*vel, 0.0])
    feet = {side: first.final_feet[side][:2].copy() for side in ("left", "right")}
    feet["left"] += [0.0, -0.01]
    planner.measured_feet_port.FixValue(context, [*feet["left"], *feet["right"], 40.0, 40.0])
    simulator.AdvanceTo(t + DT / 2)
    return planner, context, simulator, first, t, feet


def test_the_halt_is_replanned_once_on_the_measured_feet_from_the_plans_own_cog(pattern, params):
    """With ``halt_footholds`` a sole measured off the plan's foot in the halt re-plans the stop where the
    soles stand: from the plan's COG at the tick (continuous with the command, eq. 10-11; the measured COG
    is not used), on the measured feet, its ZMP continuous (eq. 12-13) and inside their support polygon, the
    COG at rest at the end; a second slide in that plan's halt does not re-plan again."""
    planner, context, simulator, first, t, feet = _in_the_halt(pattern, params, halt_footholds=True)
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(t) and new.recovery_step is False
    for side in feet:
        np.testing.assert_allclose(new.final_feet[side][:2], feet[side], atol=1e-12)
    for old_value, new_value in zip(first.com([t]), new.com([t])):  # position, velocity, acceleration, ZMP
        np.testing.assert_allclose(new_value, old_value, atol=1e-9)
    times = np.arange(t, new.halt_end + 0.5, DT)
    pos, vel, _, zmp = new.com(times)
    assert new.polygon(new.halt_end).margin(zmp).min() > 0.0
    np.testing.assert_allclose(vel[-1], 0.0, atol=1e-9)
    midpoint = 0.5 * (feet["left"] + feet["right"])
    np.testing.assert_allclose(pos[-1], midpoint, atol=0.02)
    # the robot follows the new plan into its halt, where the left sole slides another centimetre: the halt
    # is not re-planned again
    later = round((new.slowdown_end + 0.1) / DT) * DT
    for tick in range(round(t / DT) + 1, round(later / DT) + 1):
        _measure_on_the_plan(planner, context, new, tick * DT)
        simulator.AdvanceTo(tick * DT + DT / 2)
    assert planner.replans(context) == (1, 0)
    planner.measured_feet_port.FixValue(context, [*(feet["left"] + [0.0, -0.01]), *feet["right"], 40.0, 40.0])
    simulator.AdvanceTo(later + DT + DT / 2)
    assert planner.replans(context) == (1, 0) and planner.plan(context) is new


def test_without_halt_footholds_the_halt_keeps_the_plans_feet(pattern, params):
    planner, context, _, first, _, _ = _in_the_halt(pattern, params, halt_footholds=False)
    assert planner.replans(context) == (0, 0)
    assert planner.plan(context) is first


# -- a sole that re-lands off its foothold (relanded_footholds) ----------------------------------------


def _relanding(pattern, params, shift, **kwargs):
    """StopPlannerSystem beside its FootholdMonitor: the stop latched at 3.4 s; from 20 ms after the landing
    the measured COG is the plan's (the DCM on the plan) and both soles stand where the plan has them (loaded
    40 ticks); then the left sole is unloaded for 4 ticks (the robot bounced) and loaded again moved by
    ``shift`` (dx, dy), for 1 tick, then 2. Returns the planner, its context, the simulator, the first plan,
    the moved sole's position, the tick of its second loaded tick (``foothold_ticks``) and the soles' input."""
    planner, context, simulator, first, fix_feet = monitored_stop_planner(pattern, params, **kwargs)
    t = round((first.landing_time + 0.02) / DT) * DT
    simulator.AdvanceTo(t - DT / 2)
    _measure_on_the_plan(planner, context, first, t)
    feet = {side: first.final_feet[side][:2] for side in ("left", "right")}
    moved = feet["left"] + np.asarray(shift)
    steps = [(feet["left"], 40.0)] * 2 + [(feet["left"], 0.0)] * 4 + [(moved, 1.0), (moved, 2.0)]
    for k, (left, ticks) in enumerate(steps):
        fix_feet([*left, *feet["right"], ticks, 40.0])
        simulator.AdvanceTo(t + k * DT + DT / 2)
        if k < len(steps) - 1:
            assert planner.replans(context) == (0, 0), f"re-planned on step {k}"
    return planner, context, simulator, first, moved, t + (len(steps) - 1) * DT, fix_feet


def test_a_sole_that_relands_off_its_foothold_replans_the_stop_where_it_stands(pattern, params):
    """A sole that stood, lost contact (a bounce) and landed again 1 cm away re-plans the stop on its new
    foothold on its second loaded tick, with the DCM on the plan and within the re-plan interval: the other
    sole keeps the plan's foothold."""
    planner, context, simulator, first, moved, t, fix_feet = _relanding(pattern, params, (-0.01, 0.0),
                                                                         replan_interval=0.05)
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(t) and new.recovery_step is False
    np.testing.assert_allclose(new.final_feet["left"][:2], moved, atol=1e-12)
    np.testing.assert_allclose(new.final_feet["right"], first.final_feet["right"], atol=1e-12)
    # a second bounce 15 ms later, landing another centimetre back: re-planned at once again, within the
    # 50 ms re-plan interval (the sole's new place is a fact, not a deviation for the blend to remove)
    again = moved + np.array([-0.01, 0.0])
    for k, (left, ticks) in enumerate([(moved, 0.0), (again, 1.0), (again, 2.0)], start=1):
        fix_feet([*left, *first.final_feet["right"][:2], ticks, 40.0])
        simulator.AdvanceTo(t + k * DT + DT / 2)
    assert planner.replans(context) == (2, 0)
    np.testing.assert_allclose(planner.plan(context).final_feet["left"][:2], again, atol=1e-12)


@pytest.mark.parametrize("shift, kwargs", [
    ((-0.003, 0.0), {}),  # re-landed within the 5 mm tolerance
    ((-0.01, 0.0), {"relanded_footholds": False}),
    ((-0.01, 0.0), {"foothold_tolerance": 0.02}),
])
def test_a_sole_that_relands_on_its_foothold_keeps_the_plan(pattern, params, shift, kwargs):
    planner, context, _, first, _, _, _ = _relanding(pattern, params, shift, **kwargs)
    assert planner.replans(context) == (0, 0)
    assert planner.plan(context) is first


def test_a_relanded_sole_off_its_foothold_replans_through_the_foothold_replan_once_loaded(pattern, params):
    """Without ``relanded_footholds`` the foothold re-plan still stands the stop on a sole re-landed 1 cm
    back, once it has been loaded ``foothold_ticks`` ticks (not on its first loaded tick)."""
    planner, context, _, first, moved, t, _ = _relanding(pattern, params, (-0.01, 0.0), relanded_footholds=False,
                                                   foothold_replan=True)
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(t)
    np.testing.assert_allclose(new.final_feet["left"][:2], moved, atol=1e-12)


@pytest.mark.parametrize("scuff_ticks", [0, 3])
def test_the_landing_itself_is_not_a_relanding(pattern, params, scuff_ticks):
    """The landing sole's touchdown 1 cm off its target does not re-plan with the DCM on the plan (that is
    the foothold re-plan's option, off by default), also when the swinging sole scuffed the floor (loaded
    ``scuff_ticks`` ticks where the plan has it in the air) before."""
    planner, context, simulator, first, fix_feet = monitored_stop_planner(pattern, params)
    swing = first.landing_foot
    k_swing = ("left", "right").index(swing)
    feet = {side: first.final_feet[side][:2].copy() for side in ("left", "right")}
    landed = dict(feet, **{swing: feet[swing] + np.array([-0.01, 0.0])})
    ticks = [40.0, 40.0]
    for k in range(1, round((first.landing_time + 0.1 - 3.4) / DT)):
        t = 3.4 + k * DT
        _measure_on_the_plan(planner, context, first, t)
        airborne = first.feet(t)[swing][2] > 1e-9
        ticks[k_swing] = float(k) if k <= scuff_ticks else 0.0 if airborne else min(40.0, ticks[k_swing] + 1.0)
        sole = landed if t >= first.landing_time else first.feet(t)
        fix_feet([*sole["left"][:2], *sole["right"][:2], *ticks])
        simulator.AdvanceTo(t + DT / 2)
    assert planner.replans(context) == (0, 0)


def test_a_relanding_too_late_to_move_the_landing_waits_for_the_touchdown(pattern, params):
    """The support sole re-lands 1 cm back in the last ``min_landing_time`` before the touchdown, where no
    re-plan can move the landing and the double-support stop has not begun: the re-landing is kept and the
    stop is re-planned on it at the touchdown's tick."""
    planner, context, simulator, first, fix_feet = monitored_stop_planner(pattern, params)
    swing = first.landing_foot
    stance = next(side for side in ("left", "right") if side != swing)
    k_stance = ("left", "right").index(stance)
    home = first.final_feet[stance][:2].copy()
    moved = home + np.array([-0.01, 0.0])
    landing_tick = round(first.landing_time / DT)
    start = landing_tick - round(0.5 * params.min_landing_time / DT) - 4
    stance_ticks = [40.0, 40.0, 0.0, 0.0] + [float(n) for n in range(1, 30)]
    for k, loaded in enumerate(stance_ticks[:landing_tick - start + 2]):
        t = (start + k) * DT
        _measure_on_the_plan(planner, context, first, t)
        ticks = [0.0, 0.0]
        ticks[k_stance] = loaded
        ticks[1 - k_stance] = 0.0 if t < first.landing_time - 1e-9 else 40.0
        sole = {stance: home if k < 4 else moved, swing: first.final_feet[swing][:2]}
        fix_feet([*sole["left"], *sole["right"], *ticks])
        simulator.AdvanceTo(t + DT / 2)
        if t < first.landing_time - 1e-9:
            assert planner.replans(context) == (0, 0), f"re-planned at {t:.3f} s, before the touchdown"
    assert planner.replans(context) == (1, 0)
    new = planner.plan(context)
    assert new.start_time == pytest.approx(landing_tick * DT)
    np.testing.assert_allclose(new.final_feet[stance][:2], moved, atol=1e-12)


@pytest.mark.parametrize("stage, flags, expected", [
    (SOLE_STANDING, {"airborne": True, "loaded": True}, SOLE_AWAY),  # the plan lifts it: away, whatever the load
    (SOLE_AWAY, {"loaded": True}, SOLE_STANDING),
    (SOLE_AWAY, {"unloaded": True}, SOLE_AWAY),
    (SOLE_STANDING, {"loaded": True, "off": True}, SOLE_STANDING),  # a standing sole off the plan: no re-landing
    (SOLE_STANDING, {"unloaded": True}, SOLE_LIFTED),
    (SOLE_RELANDED, {"unloaded": True, "off": True}, SOLE_LIFTED),
    (SOLE_LIFTED, {}, SOLE_LIFTED),  # loaded fewer than foothold_ticks ticks
    (SOLE_LIFTED, {"loaded": True}, SOLE_STANDING),  # back on its foothold
    (SOLE_LIFTED, {"loaded": True, "off": True}, SOLE_RELANDED),
    (SOLE_RELANDED, {"loaded": True, "off": True}, SOLE_RELANDED),  # until a plan stands on it
    (SOLE_RELANDED, {"loaded": True}, SOLE_STANDING),
])
def test_a_soles_stage_follows_its_load_and_the_plan(stage, flags, expected):
    flags = {"airborne": False, "loaded": False, "unloaded": False, "off": False, **flags}
    assert next_sole_stage(stage, **flags) == expected


def test_a_sole_is_a_foothold_once_loaded_foothold_ticks_ticks():
    feet = [0.1, 0.1, 0.3, -0.1, 2.0, 1.0]  # left loaded 2 ticks, right 1
    assert foothold_loaded(feet, "left", 2) and not foothold_loaded(feet, "right", 2)
    assert foothold_loaded(feet, "right", 1) and not foothold_loaded(feet, "left", 3)
