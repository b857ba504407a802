"""The reflexes as they act on a robot (physics.reflexes): which are on for a controller and a robot, each
setting the controller leaves None taken from the robot in one place, and what apply_reflexes adds to a
diagram."""

import dataclasses

import pytest
from test_robots import needs_robot_data

from drake_estop.physics.controller_options import (
    ControllerOptions,
    FootEdgeComplianceConfig,
    FootForceConfig,
    HipStrategyConfig,
    SwingTiltConfig,
)
from drake_estop.physics.reflexes import EDGE_MARGIN, SWING_TILT_DEADBAND, Reflexes
from drake_estop.robots import load_robot


def test_the_default_controller_on_the_default_humanoid():
    """Swing tilt, foot force control (its damping and engage time from the description) and the edge
    compliance on, at the benchmarked settings; the hip strategy off."""
    robot = load_robot("default")
    reflexes = Reflexes.of(ControllerOptions(), robot)
    assert reflexes.swing_tilt == SwingTiltConfig(deadband=SWING_TILT_DEADBAND)
    assert reflexes.foot_compliance == FootEdgeComplianceConfig(edge_margin=EDGE_MARGIN)
    assert reflexes == Reflexes(foot_force=reflexes.foot_force)  # the resolved defaults
    assert reflexes.foot_force == FootForceConfig(damping=robot.foot_force_damping,
                                                  engage_time=robot.foot_force_engage_time)
    assert reflexes.hip_strategy is None


def test_a_feature_turned_off_is_none_and_the_hip_strategy_on_is_its_config():
    off = ControllerOptions(swing_tilt=None, foot_force=None, foot_compliance=None, hip_strategy=HipStrategyConfig())
    reflexes = Reflexes.of(off, "default")
    assert (reflexes.swing_tilt, reflexes.foot_force, reflexes.foot_compliance) == (None, None, None)
    assert reflexes.hip_strategy == HipStrategyConfig()


@needs_robot_data
def test_a_robots_own_settings_replace_the_defaults_and_a_robot_without_a_damping_has_no_foot_force_control():
    g1 = load_robot("g1")
    reflexes = Reflexes.of(ControllerOptions(), g1)
    assert reflexes.swing_tilt.deadband == g1.swing_tilt_deadband != SWING_TILT_DEADBAND
    assert reflexes.foot_compliance.edge_margin == g1.foot_edge_margin != EDGE_MARGIN
    assert g1.foot_force_damping is None and reflexes.foot_force is None


@needs_robot_data
def test_a_setting_the_controller_gives_beats_the_robots_own():
    g1 = load_robot("g1")
    controller = ControllerOptions(swing_tilt=SwingTiltConfig(deadband=0.03),
                                   foot_compliance=FootEdgeComplianceConfig(edge_margin=0.02),
                                   foot_force=FootForceConfig(damping=3000.0))
    reflexes = Reflexes.of(controller, g1)
    assert (reflexes.swing_tilt.deadband, reflexes.foot_compliance.edge_margin) == (0.03, 0.02)
    assert reflexes.foot_force.damping == 3000.0  # a damping given turns the control on for a robot without one


def test_the_foot_force_settings_leave_out_an_engage_time_the_robot_does_not_give():
    assert FootForceConfig(damping=4000.0).settings() == {"damping": 4000.0, "return_time": 0.5, "max_offset": 0.02,
                                                         "planned_support": False}
    assert FootForceConfig(damping=4000.0, engage_time=0.2).settings()["engage_time"] == 0.2


def test_the_configs_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        SwingTiltConfig().deadband = 0.0
