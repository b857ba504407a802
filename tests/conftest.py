"""Shared fixtures: the default gait and the stop plans for every servo tick of one stride."""

import pytest

from drake_estop.planning.gait import NominalPattern
from drake_estop.planning.planner import StopParameters, plan_stop
from drake_estop.planning.rollout import stride_ticks


@pytest.fixture(scope="session")
def pattern():
    return NominalPattern()


@pytest.fixture(scope="session")
def params():
    return StopParameters()


@pytest.fixture(scope="session")
def stride_times(pattern, params):
    """Every servo tick of one stride (single + double support of the third step)."""
    return stride_ticks(pattern, params)


@pytest.fixture(scope="session")
def stride_plans(pattern, params, stride_times):
    return [plan_stop(pattern, t, params) for t in stride_times]
