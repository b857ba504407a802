"""The public API of ``drake_estop``: every exported name imports, is documented with
numpydoc sections and units, LeafSystems carry a ``.. pydrake_system::`` block, and
``AddEmergencyStop`` rejects bad arguments with errors that name them."""

import inspect
import re
import subprocess
import sys

import pytest
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder, LeafSystem

import drake_estop

NAMES = [name for name in drake_estop.__all__ if name != "__version__"]
# a unit in brackets ([m], [s], [rad], [m/s], [N s], ...) or an explicit "dimensionless"
UNIT = re.compile(r"\[(m|s|rad|N|kg|m/s|rad/s|m/s\^2|N s|N m/rad|1/s\^2|1/m\^2|1/\(m/s\)\^2|m, rad)\]"
                  r"|dimensionless|no physical units")
SECTION = re.compile(r"^\s*(Parameters|Attributes|Returns)\n\s*-{5,}$", re.M)


def test_every_public_name_imports_from_the_package():
    for name in NAMES:
        namespace = {}
        exec(f"from drake_estop import {name}", namespace)  # noqa: S102 - the user's own spelling
        assert namespace[name] is getattr(drake_estop, name)


def test_the_stop_controller_module_offers_the_stops_leaf_systems():
    """The stop's public LeafSystems import from ``drake_estop.systems.stop_controller`` as well."""
    from drake_estop.systems import stop_controller

    for name in ("WalkingPatternSource", "EStopTrigger", "StopPlannerSystem"):
        assert getattr(stop_controller, name) is getattr(drake_estop, name)


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'NoSuchThing'"):
        drake_estop.NoSuchThing  # noqa: B018


def test_import_is_lazy():
    code = "import sys, drake_estop; print('pydrake' in sys.modules, 'drake_estop.planning.planner' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


@pytest.mark.parametrize("name", [n for n in NAMES if n != "PHASES"])
def test_numpydoc_docstring_with_units(name):
    obj = getattr(drake_estop, name)
    doc = inspect.getdoc(obj) or ""
    if name == "InfeasibleStop":  # an exception: its message names the limit
        assert "names the limit" in doc
        return
    assert SECTION.search(doc), f"{name}: no numpydoc Parameters/Attributes/Returns section"
    assert UNIT.search(doc), f"{name}: no unit in its docstring"


def test_phases_is_documented_in_its_module():
    source = inspect.getsource(sys.modules[drake_estop._EXPORTS["PHASES"]])
    assert re.search(r'^PHASES = .*\n"""Phase labels', source, re.M)


@pytest.mark.parametrize("name", NAMES)
def test_leaf_systems_carry_a_pydrake_system_block(name):
    obj = getattr(drake_estop, name)
    if inspect.isclass(obj) and issubclass(obj, LeafSystem):
        doc = inspect.getdoc(obj)
        assert ".. pydrake_system::" in doc and f"name: {name}" in doc


def test_every_exported_leaf_system_is_checked():
    systems = {n for n in NAMES if inspect.isclass(getattr(drake_estop, n))
               and issubclass(getattr(drake_estop, n), LeafSystem)}
    assert {"WalkingPatternSource", "EStopTrigger", "StopPlannerSystem", "WholeBodyIK"} <= systems


def test_add_emergency_stop_rejects_an_unfinalized_plant():
    plant = MultibodyPlant(0.0)
    drake_estop.load_humanoid(plant)
    with pytest.raises(ValueError, match="plant must be finalized"):
        drake_estop.AddEmergencyStop(DiagramBuilder(), plant=plant)


def test_add_emergency_stop_rejects_a_plant_without_the_humanoid():
    plant = MultibodyPlant(0.0)
    plant.Finalize()
    with pytest.raises(ValueError, match="plant lacks the humanoid's joints"):
        drake_estop.AddEmergencyStop(DiagramBuilder(), plant=plant)


def test_add_emergency_stop_rejects_a_bad_estop_time():
    with pytest.raises(ValueError, match="estop_time"):
        drake_estop.AddEmergencyStop(DiagramBuilder(), estop_time=float("nan"))


def test_arguments_are_keyword_only():
    with pytest.raises(TypeError):
        drake_estop.AddEmergencyStop(DiagramBuilder(), None)


def test_reading_the_summary_before_the_latch_says_so():
    from pydrake.systems.analysis import Simulator

    builder = DiagramBuilder()
    estop = drake_estop.AddEmergencyStop(builder, estop_time=3.4, log=False)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.1)
    with pytest.raises(RuntimeError, match="has not latched by t = 0.100 s"):
        estop.summary(simulator.get_context())
    with pytest.raises(RuntimeError, match="log=False"):
        estop.log(simulator.get_context())


def test_a_users_plant_in_the_diagram_is_left_for_the_user_to_drive():
    """With a plant that is a system of the diagram (e.g. physics), q is exported for the user's servos."""
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=1e-3)
    drake_estop.load_humanoid(plant)
    plant.Finalize()
    estop = drake_estop.AddEmergencyStop(builder, plant=plant, scene_graph=scene_graph, log=False)
    assert estop.plant is plant
    assert not any(s.get_name() == "q_to_pose" for s in builder.GetSystems())
    assert estop.q.size() == plant.num_positions()
    builder.ExportOutput(estop.q, "q")
    builder.Build()


def test_a_users_scene_graph_gets_the_robot_posed_in_it():
    from pydrake.geometry import SceneGraph
    from pydrake.systems.analysis import Simulator

    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    estop = drake_estop.AddEmergencyStop(builder, scene_graph=scene_graph, estop_time=0.5)
    assert estop.scene_graph is scene_graph and estop.plant.geometry_source_is_registered()
    assert any(s.get_name() == "q_to_pose" for s in builder.GetSystems())
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.6)
    assert estop.plan(simulator.get_context()).signal_time == pytest.approx(0.5)


def test_meshcat_without_a_scene_graph_is_refused():
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph

    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, time_step=1e-3)
    drake_estop.load_humanoid(plant)
    plant.Finalize()
    with pytest.raises(ValueError, match="meshcat needs a scene_graph"):
        drake_estop.AddEmergencyStop(builder, plant=plant, meshcat=object())
