"""The live stop button, end to end: a browser's button message reaches Meshcat's
websocket, the trigger latches at the next servo tick and the planner stops the robot.

The click is injected with ``Meshcat._InjectWebsocketMessage`` (what Drake's own
Meshcat tests do) as the msgpack message a browser sends for a button press.
"""

import numpy as np
from pydrake.systems.analysis import Simulator

from drake_estop.planning.gait import GaitParameters
from drake_estop.planning.planner import StopParameters
from drake_estop.systems.diagram import build_diagram
from drake_estop.systems.visualization import make_meshcat


def _msgpack_str(text: str) -> bytes:
    data = text.encode()
    assert len(data) < 32
    return bytes([0xA0 | len(data)]) + data


def _button_click(name: str) -> bytes:
    """msgpack of {"type": "button", "name": name} (fixmap of two fixstr pairs)."""
    return (bytes([0x82]) + _msgpack_str("type") + _msgpack_str("button")
            + _msgpack_str("name") + _msgpack_str(name))


def test_button_press_stops_the_walking_robot():
    meshcat = make_meshcat()
    handles = build_diagram(gait_params=GaitParameters(), stop_params=StopParameters(), estop_time=None,
                            meshcat=meshcat)
    simulator = Simulator(handles.diagram)
    simulator.Initialize()
    context = simulator.get_mutable_context()
    planner_context = handles.planner.GetMyContextFromRoot(context)
    simulator.AdvanceTo(3.0)
    assert handles.planner.plan(planner_context) is None  # still walking
    name = handles.trigger.button_name
    meshcat._InjectWebsocketMessage(message=_button_click(name))
    assert meshcat.GetButtonClicks(name) == 1
    simulator.AdvanceTo(3.1)
    plan = handles.planner.plan(planner_context)
    assert plan is not None
    assert 3.0 <= plan.signal_time <= 3.0 + 2 * plan.params.servo_period
    # a second press after the latch changes nothing
    meshcat._InjectWebsocketMessage(message=_button_click(name))
    simulator.AdvanceTo(plan.halt_end + 0.5)
    again = handles.planner.plan(planner_context)
    assert again.signal_time == plan.signal_time
    assert plan.halt_end < handles.pattern.end_time
    vel = plan.com([plan.halt_end + 0.5])[1]
    assert np.linalg.norm(vel) < 1e-6
