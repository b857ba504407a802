"""DcmStabilizer, CogMeasurement and DesiredStateInterpolator in isolation."""

import math

import numpy as np
import pytest
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator

from drake_estop.model import load_humanoid, nominal_standing_configuration
from drake_estop.physics.stabilizer import (
    CogMeasurement,
    DcmStabilizer,
    DesiredStateInterpolator,
    saturation_scale,
    support_corners,
)
from drake_estop.planning.gait import Sole
from drake_estop.planning.lipm import GRAVITY

G = GRAVITY
Z = 0.8
OMEGA = math.sqrt(G / Z)
LEVEL = [1.0, 0.0, 0.0, 0.0]
LEFT = np.array([0.0, 0.095, 0.0, *LEVEL])
RIGHT = np.array([0.0, -0.095, 0.0, *LEVEL])
SOLE = Sole()


def _fixed(stab, context, *, com=(0.0, 0.0), vel=(0.0, 0.0), zmp=(0.0, 0.0), meas=None, meas_vel=None,
           cop=None, left=LEFT, right=RIGHT):
    meas = com if meas is None else meas
    meas_vel = vel if meas_vel is None else meas_vel
    stab.planned_com_port.FixValue(context, [*com, Z])
    stab.planned_com_vel_port.FixValue(context, [*vel, 0.0])
    stab.planned_zmp_port.FixValue(context, list(zmp))
    stab.measured_com_port.FixValue(context, [*meas, Z])
    stab.measured_com_vel_port.FixValue(context, [*meas_vel, 0.0])
    stab.measured_cop_port.FixValue(context, list(zmp if cop is None else cop))
    stab.left_foot_port.FixValue(context, left)
    stab.right_foot_port.FixValue(context, right)


def _step(stab, context):
    context.SetDiscreteState(stab.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())


def _unfiltered(**kw):
    return DcmStabilizer(dcm_filter_time_constant=0.0, **kw)


def test_ports_and_keyword_only():
    stab = DcmStabilizer()
    assert [stab.get_input_port(i).get_name() for i in range(stab.num_input_ports())] == [
        "planned_com", "planned_com_vel", "planned_zmp", "measured_com", "measured_com_vel",
        "measured_cop", "left_foot", "right_foot"]
    assert [stab.get_output_port(i).get_name() for i in range(stab.num_output_ports())] == [
        "com", "commanded_zmp", "com_offset", "dcm_error"]
    with pytest.raises(TypeError):
        DcmStabilizer(0.005)  # noqa
    with pytest.raises(ValueError):
        DcmStabilizer(k_dcm=0.0)


def test_zero_error_gives_zero_correction_in_simulator():
    stab = DcmStabilizer()
    simulator = Simulator(stab)
    context = simulator.get_mutable_context()
    _fixed(stab, context, com=(0.02, 0.01), vel=(0.1, -0.05), zmp=(0.01, 0.02))
    simulator.Initialize()
    simulator.AdvanceTo(0.5)
    np.testing.assert_array_equal(stab.com_offset_port.Eval(context), [0.0, 0.0])
    np.testing.assert_array_equal(stab.com_port.Eval(context), [0.02, 0.01, Z])
    np.testing.assert_array_equal(stab.commanded_zmp_port.Eval(context), [0.01, 0.02])
    np.testing.assert_array_equal(stab.dcm_error_port.Eval(context), [0.0, 0.0])
    assert stab.saturation(context) == 1.0


def test_zero_error_near_an_edge_is_not_moved_by_the_margin():
    # the plan may put its ZMP closer than zmp_margin to the toe: that is left alone
    stab = DcmStabilizer(zmp_margin=0.02)
    context = stab.CreateDefaultContext()
    zmp = (SOLE.toe - 0.005, 0.0)
    _fixed(stab, context, zmp=zmp)
    for _ in range(10):
        _step(stab, context)
    np.testing.assert_allclose(stab.commanded_zmp_port.Eval(context), zmp, atol=1e-15)
    np.testing.assert_array_equal(stab.com_offset_port.Eval(context), [0.0, 0.0])


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_sign_of_the_correction(axis, sign):
    # the robot's COG is ahead of the plan along +axis: the ZMP must move ahead (to push the DCM
    # back) and the commanded COG must accelerate back (negative offset rate and then offset)
    stab = _unfiltered(k_dcm=3.0)
    context = stab.CreateDefaultContext()
    meas = np.zeros(2)
    meas[axis] = sign * 0.005
    _fixed(stab, context, meas=meas)
    _step(stab, context)
    p_cmd = stab.commanded_zmp_port.Eval(context)
    assert sign * p_cmd[axis] == pytest.approx((1.0 + 3.0 / OMEGA) * 0.005, rel=1e-12)
    assert p_cmd[1 - axis] == 0.0
    assert stab.dcm_error_port.Eval(context)[axis] == pytest.approx(sign * 0.005)
    for _ in range(20):
        _step(stab, context)
    offset = stab.com_offset_port.Eval(context)
    assert sign * offset[axis] < -1e-5 and offset[1 - axis] == 0.0
    com = stab.com_port.Eval(context)
    assert sign * com[axis] < 0 and com[2] == Z  # height is passed through


def test_velocity_error_counts_through_the_dcm():
    stab = _unfiltered(k_dcm=3.0)
    context = stab.CreateDefaultContext()
    _fixed(stab, context, meas_vel=(0.035, 0.0))
    _step(stab, context)
    assert stab.dcm_error_port.Eval(context)[0] == pytest.approx(0.035 / OMEGA)


def test_dcm_filter_lags_the_error():
    stab = DcmStabilizer(dcm_filter_time_constant=0.1)
    context = stab.CreateDefaultContext()
    _fixed(stab, context, meas=(0.01, 0.0))
    _step(stab, context)
    beta = 0.005 / (0.1 + 0.005)
    gain = 1.0 + stab.k_dcm / OMEGA
    assert stab.commanded_zmp_port.Eval(context)[0] == pytest.approx(gain * beta * 0.01)


def test_saturation_keeps_commanded_zmp_inside_the_support_polygon():
    margin = 0.01
    stab = _unfiltered(k_dcm=3.0, zmp_margin=margin)
    context = stab.CreateDefaultContext()
    _fixed(stab, context, meas=(0.3, 0.05))  # 30 cm ahead: far outside
    _step(stab, context)
    p_cmd = stab.commanded_zmp_port.Eval(context)
    gain = 1.0 + 3.0 / OMEGA
    assert stab.saturation(context) == pytest.approx((SOLE.toe - margin) / (gain * 0.3), rel=1e-9)
    # on the toe line minus the margin, in the direction of the error
    assert p_cmd[0] == pytest.approx(SOLE.toe - margin, abs=1e-12)
    assert p_cmd[1] == pytest.approx(p_cmd[0] * 0.05 / 0.3, rel=1e-9)  # direction kept


def test_saturation_uses_the_stance_foot_in_single_support():
    margin = 0.01
    stab = _unfiltered(k_dcm=3.0, zmp_margin=margin)
    context = stab.CreateDefaultContext()
    lifted = RIGHT.copy()
    lifted[2] = 0.03  # right foot in the air: support = left sole only
    zmp = (0.0, 0.095)
    _fixed(stab, context, zmp=zmp, com=zmp, meas=(0.0, 0.095 - 0.2), right=lifted)
    _step(stab, context)
    p_cmd = stab.commanded_zmp_port.Eval(context)
    assert p_cmd[1] == pytest.approx(0.095 - SOLE.inner + margin, abs=1e-12)  # left sole's inner edge
    # with both feet down the same error is not saturated
    context2 = stab.CreateDefaultContext()
    _fixed(stab, context2, zmp=zmp, com=zmp, meas=(0.0, 0.095 - 0.02))
    _step(stab, context2)
    assert stab.saturation(context2) == 1.0


def test_saturation_scale_helper():
    corners = support_corners(LEFT, RIGHT, SOLE)
    assert corners.shape == (8, 2)
    assert saturation_scale([0.0, 0.0], [0.0, 0.0], corners, 0.01) == 1.0
    assert saturation_scale([0.0, 0.0], [0.25, 0.0], corners, 0.01) == pytest.approx(0.125 / 0.25)
    # p_ref outside the margin band: only inward corrections
    assert saturation_scale([SOLE.toe - 0.001, 0.0], [0.01, 0.0], corners, 0.01) == 0.0
    assert saturation_scale([SOLE.toe - 0.001, 0.0], [-0.01, 0.0], corners, 0.01) == 1.0
    lifted = RIGHT.copy()
    lifted[2] = 0.01
    assert support_corners(LEFT, lifted, SOLE).shape == (4, 2)
    yawed = LEFT.copy()
    yawed[3:] = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]  # 90 deg yaw
    rotated = support_corners(yawed, lifted, SOLE)
    assert np.max(rotated[:, 1]) == pytest.approx(0.095 + SOLE.toe)


def test_ideal_tracking_loop_converges_with_the_documented_static_gain():
    # perfect servos: measured COG = planned + offset + a constant measurement bias b;
    # the loop settles (offset rate -> 0) at offset = -(1 + omega / k) b
    stab = DcmStabilizer(k_dcm=2.0, dcm_filter_time_constant=0.1)
    context = stab.CreateDefaultContext()
    bias = np.array([0.002, -0.001])
    _fixed(stab, context)
    for _ in range(3000):  # 15 s
        offset = stab.com_offset_port.Eval(context)
        rate = context.get_discrete_state(0).value()[2:4]
        stab.measured_com_port.FixValue(context, [*(offset + bias), Z])
        stab.measured_com_vel_port.FixValue(context, [*rate, 0.0])
        _step(stab, context)
    np.testing.assert_allclose(stab.com_offset_port.Eval(context), -(1 + OMEGA / 2.0) * bias, rtol=1e-3)
    assert np.all(np.abs(context.get_discrete_state(0).value()[2:4]) < 1e-6)


def test_model_error_estimate_follows_the_cop():
    stab = _unfiltered(k_model=1.0, model_error_time_constant=0.02)
    context = stab.CreateDefaultContext()
    _fixed(stab, context, cop=(0.03, 0.0))
    for _ in range(40):
        _step(stab, context)
    d_hat = stab.model_error(context)
    assert d_hat[0] > 0.02  # the CoP is ahead of the LIPM ZMP of the commanded motion
    # cancelling it moves the LIPM ZMP of the commanded COG back: the commanded COG accelerates forward
    assert stab.com_offset_port.Eval(context)[0] > 0
    nan = stab.CreateDefaultContext()
    _fixed(stab, nan, cop=(np.nan, np.nan))
    _step(stab, nan)
    np.testing.assert_array_equal(stab.model_error(nan), [0.0, 0.0])


# -- measurement and joint targets ---------------------------------------------


@pytest.fixture(scope="module")
def plant():
    plant = MultibodyPlant(1e-3)
    load_humanoid(plant)
    plant.Finalize()
    return plant


def test_cog_measurement_matches_the_plant(plant):
    meas = CogMeasurement(plant=plant)
    assert [meas.get_output_port(i).get_name() for i in range(2)] == ["com", "com_vel"]
    context = meas.CreateDefaultContext()
    q = nominal_standing_configuration(plant)
    rng = np.random.default_rng(0)
    v = rng.normal(size=plant.num_velocities()) * 0.1
    meas.state_port.FixValue(context, np.concatenate([q, v]))
    scratch = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(scratch, np.concatenate([q, v]))
    np.testing.assert_allclose(meas.com_port.Eval(context), plant.CalcCenterOfMassPositionInWorld(scratch))
    np.testing.assert_allclose(meas.com_vel_port.Eval(context),
                               plant.CalcCenterOfMassTranslationalVelocityInWorld(scratch))


@pytest.mark.parametrize("mode", ["interpolate", "extrapolate"])
def test_desired_state_interpolator(mode):
    dt = 0.005
    q0 = np.array([9.0, 1.0, 2.0])
    system = DesiredStateInterpolator(q_indices=[1, 2], initial_q=q0, servo_period=dt, mode=mode)
    context = system.CreateDefaultContext()
    system.q_port.FixValue(context, q0)
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context).get_vector().value())
    np.testing.assert_allclose(system.desired_state_port.Eval(context), [1.0, 2.0, 0.0, 0.0])
    # next tick: the source moved to q1; the state remembers q0 and the tick time
    q1 = np.array([9.0, 1.01, 1.98])
    system.q_port.FixValue(context, q1)
    context.SetTime(dt / 2)
    v = (q1[1:] - q0[1:]) / dt
    base = q0[1:] if mode == "interpolate" else q1[1:]
    np.testing.assert_allclose(system.desired_state_port.Eval(context), [*(base + v * dt / 2), *v])
    with pytest.raises(ValueError):
        DesiredStateInterpolator(q_indices=[0], initial_q=q0, mode="spline")
