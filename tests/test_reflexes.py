"""The reflexes as typed configuration (physics.reflexes): which are on for a controller and a robot, with the
robot's own settings taken in one place, and what apply_reflexes adds to a diagram."""

import dataclasses

import pytest
from test_robots import needs_robot_data

from drake_estop.physics.controller_options import ControllerOptions
from drake_estop.physics.reflexes import (
    FootEdgeComplianceConfig,
    FootForceConfig,
    HipStrategyConfig,
    Reflexes,
    SwingTiltConfig,
)
from drake_estop.robots import load_robot


def test_the_default_controller_on_the_default_humanoid():
    """Swing tilt, foot force control (its damping and engage time from the description) and the edge
    compliance on, at the benchmarked settings; the hip strategy off."""
    robot = load_robot("default")
    reflexes = Reflexes.of(ControllerOptions(), robot)
    assert reflexes.swing_tilt == SwingTiltConfig() and reflexes.foot_compliance == FootEdgeComplianceConfig()
    assert reflexes.foot_force == FootForceConfig(damping=robot.foot_force_damping,
                                                  engage_time=robot.foot_force_engage_time)
    assert reflexes.hip_strategy is None


def test_a_feature_turned_off_is_none_and_the_hip_strategy_on_is_its_config():
    off = ControllerOptions(swing_tilt=False, foot_force_control=False, foot_compliance=False, hip_strategy=True)
    reflexes = Reflexes.of(off, "default")
    assert (reflexes.swing_tilt, reflexes.foot_force, reflexes.foot_compliance) == (None, None, None)
    assert reflexes.hip_strategy == HipStrategyConfig()


@needs_robot_data
def test_a_robots_own_settings_replace_the_defaults_and_a_robot_without_a_damping_has_no_foot_force_control():
    g1 = load_robot("g1")
    reflexes = Reflexes.of(ControllerOptions(), g1)
    assert reflexes.swing_tilt.deadband == g1.swing_tilt_deadband != SwingTiltConfig().deadband
    assert reflexes.foot_compliance.edge_margin == g1.foot_edge_margin != FootEdgeComplianceConfig().edge_margin
    assert g1.foot_force_damping is None and reflexes.foot_force is None


def test_the_foot_force_settings_leave_out_an_engage_time_the_robot_does_not_give():
    assert FootForceConfig(damping=4000.0).settings() == {"damping": 4000.0, "return_time": 0.5, "max_offset": 0.02}
    assert FootForceConfig(damping=4000.0, engage_time=0.2).settings()["engage_time"] == 0.2


def test_the_configs_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        SwingTiltConfig().deadband = 0.0
