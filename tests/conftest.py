"""Shared fixtures: the default gait and the stop plans for every servo tick of one stride."""

import numpy as np
import pytest

from drake_estop.gait import NominalPattern
from drake_estop.planner import StopParameters, plan_stop

STRIDE_START = 2.8  # liftoff of the third step of the default walk
STRIDE_TICKS = 160  # 0.8 s at 5 ms: single + double support of one step


@pytest.fixture(scope="session")
def pattern():
    return NominalPattern()


@pytest.fixture(scope="session")
def params():
    return StopParameters()


@pytest.fixture(scope="session")
def stride_times(params):
    return STRIDE_START + params.servo_period * np.arange(STRIDE_TICKS)


@pytest.fixture(scope="session")
def stride_plans(pattern, params, stride_times):
    return [plan_stop(pattern, t, params) for t in stride_times]
