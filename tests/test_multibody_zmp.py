"""The whole body's ZMP of the IK's joint trajectory (drake_estop.systems.multibody_zmp): the LIPM's where
the limbs add no angular momentum, the swing legs' share where they do, and its margin in the soles."""

import numpy as np
import pytest
from robot_helpers import needs_robots

from drake_estop.planning.gait import Sole
from drake_estop.systems.ik import shared_ik
from drake_estop.systems.multibody_zmp import multibody_zmp, support_margins

DT = 0.005
GRAVITY = -shared_ik(None)[0].gravity_field().gravity_vector()[2]  # the IK plant's (the LIPM's, 9.80665)


def _standing(n=20):
    plant, _, _ = shared_ik(None)
    context = plant.CreateDefaultContext()
    q = np.tile(plant.GetPositions(context), (n, 1))
    q[:, 6] = 0.7  # the floating base's z: above the floor
    return plant, q


def _com(plant, q):
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    return plant.CalcCenterOfMassPositionInWorld(context)


def test_a_body_at_rest_has_its_zmp_under_its_cog():
    plant, q = _standing()
    zmp = multibody_zmp(plant, q, DT)
    np.testing.assert_allclose(zmp, np.tile(_com(plant, q[0])[:2], (len(q), 1)), atol=1e-9)


def test_a_translating_body_has_the_lipm_zmp():
    """The base translated at a constant acceleration, no rotation and no joint moving: no angular momentum
    about the COG, so the ZMP is the LIPM's (eq. 4), c - c_z a / g, on every tick whose averaging window
    lies inside the run (the ends are one-sided)."""
    plant, q = _standing(40)
    times = DT * np.arange(len(q))
    acceleration = np.array([1.5, -0.8])
    q[:, 4:6] += 0.5 * np.outer(times ** 2, acceleration)
    zmp = multibody_zmp(plant, q, DT)
    com = np.array([_com(plant, row) for row in q])
    expected = com[:, :2] - com[:, 2:3] * acceleration / GRAVITY
    np.testing.assert_allclose(zmp[6:-6], expected[6:-6], atol=1e-6)


def test_a_swinging_leg_moves_the_zmp_against_its_angular_momentum():
    """One hip pitching forward and back at 1.5 Hz, the base held: the LIPM's ZMP (the COG's horizontal
    acceleration only) misses the leg's angular momentum about the COG; the whole body's includes it, and
    the two differ by more than a centimetre."""
    plant, q = _standing(200)
    joint = plant.GetJointByName("l_hip_pitch")
    times = DT * np.arange(len(q))
    q[:, joint.position_start()] = 0.4 * np.sin(2 * np.pi * 1.5 * times)
    zmp = multibody_zmp(plant, q, DT)
    com = np.array([_com(plant, row) for row in q])
    acceleration = np.gradient(np.gradient(com, DT, axis=0), DT, axis=0)
    lipm = com[:, 0] - com[:, 2] * acceleration[:, 0] / (GRAVITY + acceleration[:, 2])
    assert np.abs(zmp[5:-5, 0] - lipm[5:-5]).max() > 0.01
    # the COG given by a caller that has it (the diagram's result) is the one computed here: the same ZMP
    np.testing.assert_array_equal(multibody_zmp(plant, q, DT, com=com), zmp)


def test_the_margin_is_in_the_soles_on_the_floor():
    sole = Sole(toe=0.13, heel=0.11, inner=0.068, outer=0.068)
    level = [1.0, 0.0, 0.0, 0.0]
    feet = {"left": np.array([[0.0, 0.1, 0.0, *level], [0.0, 0.1, 0.05, *level], [0.0, 0.1, 0.05, *level]]),
            "right": np.array([[0.0, -0.1, 0.0, *level], [0.0, -0.1, 0.0, *level], [0.0, -0.1, 0.05, *level]])}
    zmp = np.array([[0.0, 0.0], [0.0, -0.1], [0.0, 0.0]])
    margins = support_margins(zmp, feet, sole)
    # both soles: between the feet, 0.13 m from the toes' edge and 0.11 from the heels'; the right alone: its
    # centre, 0.068 m from its sides; no sole on the floor: NaN
    np.testing.assert_allclose(margins[:2], [0.11, 0.068], atol=1e-9)
    assert np.isnan(margins[2])


def test_bad_input_names_the_argument():
    plant, q = _standing()
    with pytest.raises(ValueError, match="q must be"):
        multibody_zmp(plant, q[:2], DT)
    with pytest.raises(ValueError, match="q must be"):
        multibody_zmp(plant, q[:, :-1], DT)
    with pytest.raises(ValueError, match="dt must be positive"):
        multibody_zmp(plant, q, 0.0)
    with pytest.raises(ValueError, match="window must be finite and non-negative"):
        multibody_zmp(plant, q, DT, window=-0.01)
    with pytest.raises(ValueError, match="com must be"):
        multibody_zmp(plant, q, DT, com=np.zeros((len(q) - 1, 3)))


def test_a_landing_transient_is_averaged_over_the_window():
    """A stop signalled 15 ms before the 3.5 s touchdown on the default humanoid: the swing foot brakes onto
    the floor within a few ticks, and the instantaneous ZMP (no averaging) leaves the soles by 63 mm for
    20 ms; averaged over 50 ms (the default) it stays 6 mm inside. Measured, both."""
    from drake_estop.systems.diagram import simulate_diagram

    result = simulate_diagram(estop_time=3.485)
    plant, _, _ = shared_ik(None)
    feet = {"left": result.logged_reference["left_foot"], "right": result.logged_reference["right_foot"]}
    instantaneous = support_margins(multibody_zmp(plant, result.q_full, DT, window=0.0), feet,
                                    result.plan.pattern.params.sole)
    assert np.nanmin(instantaneous) < -0.03 < 0.0 < result.error_summary()["stop_multibody_zmp_margin_min_m"]
    # the result's ZMP (on the COG the result computed for the IK's errors) is this function's on its q
    np.testing.assert_array_equal(result.multibody_zmp, multibody_zmp(plant, result.q_full, DT))


def test_the_default_humanoid_s_stop_keeps_the_whole_body_zmp_in_its_soles():
    """The paper's 3.4 s stop on the default humanoid: the kinematic diagram reports the whole body's ZMP
    margin, least over the run and over the stop, and both are positive (measured 49 mm, in the stop, against
    the plan's LIPM 52 mm: its light legs shift the ZMP by a few millimetres)."""
    from drake_estop.systems.diagram import simulate_diagram

    result = simulate_diagram(estop_time=3.4)
    summary = result.error_summary()
    assert result.multibody_zmp.shape == (len(result.times), 2)
    assert 0.02 < summary["stop_multibody_zmp_margin_min_m"] and 0.02 < summary["multibody_zmp_margin_min_m"]


@needs_robots
def test_the_g1_s_own_walk_asks_for_a_zmp_behind_its_heel():
    """The G1's own gait (0.27 m steps in 0.79 s; each leg 7 of its 33 kg): the plan's LIPM ZMP stays
    12 mm inside the soles, but the swing leg's angular momentum puts the whole body's ZMP 14 mm outside
    (behind the stance heel, late in the second step's single support), and 10 mm outside in the stop:
    the check finds, before any physics, why that walk falls on the contact plant."""
    from drake_estop.systems.diagram import simulate_diagram
    from drake_estop.systems.multibody_zmp import support_margins as margins_of

    result = simulate_diagram(estop_time=3.4, robot="g1")
    feet = {"left": result.logged_reference["left_foot"], "right": result.logged_reference["right_foot"]}
    lipm = margins_of(result.zmp, feet, result.plan.pattern.params.sole)
    assert np.nanmin(lipm) > 0.005
    assert result.error_summary()["multibody_zmp_margin_min_m"] < -0.005


def test_the_zmp_takes_the_plant_s_gravity():
    """A plant under 5 m/s^2: the translating base's ZMP is c - c_z a / 5 (the gravity the plant has, not a
    constant)."""
    from pydrake.multibody.plant import MultibodyPlant

    from drake_estop.model import load_humanoid

    plant = MultibodyPlant(0.0)
    load_humanoid(plant)
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -5.0])
    plant.Finalize()
    q = np.tile(plant.GetPositions(plant.CreateDefaultContext()), (40, 1))
    q[:, 6] = 0.7
    times = DT * np.arange(len(q))
    q[:, 4] += 0.5 * 1.5 * times ** 2
    zmp = multibody_zmp(plant, q, DT)
    com = np.array([_com(plant, row) for row in q])
    np.testing.assert_allclose(zmp[6:-6, 0], com[6:-6, 0] - com[6:-6, 2] * 1.5 / 5.0, atol=1e-6)
