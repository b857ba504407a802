"""Perturbations of the simulated robot: validation, CLI options, model errors, friction, pushes."""

import argparse

import numpy as np
import pytest
from pydrake.multibody.plant import CalcContactFrictionFromSurfaceProperties, CoulombFriction
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from drake_estop.model import FLOATING_BASE, TORSO
from drake_estop.physics.perturbations import (
    SOLE_MU_DYNAMIC,
    SOLE_MU_STATIC,
    PelvisPush,
    Perturbations,
    Push,
    add_pelvis_push,
    add_perturbation_arguments,
    apply_model_errors,
    ground_friction,
    perturbations_from_args,
    perturbed_ground,
)
from drake_estop.physics.plant import FloorDrop, PhysicsParameters, actuated_indices, add_physics_plant


def _parse(*argv):
    parser = add_perturbation_arguments(argparse.ArgumentParser())
    return perturbations_from_args(parser.parse_args(list(argv)))


# --------------------------------------------------------------------------
# Validation and options.


def test_defaults_are_the_nominal_robot():
    p = _parse()
    assert p == Perturbations()
    assert not p.model_error and p.pushes == () and p.friction is None


def test_every_option_parses():
    p = _parse("--push", "3.4", "170", "0", "0.1", "--push", "4", "0", "-50", "0.2",
               "--mass-scale", "1.1", "--torso-mass-scale", "0.9", "--torso-com-offset", "-0.02",
               "--friction", "0.5", "--latency", "2", "--sensor-noise", "--seed", "7")
    assert p.pushes == (Push(3.4, 170.0, 0.0, 0.1), Push(4.0, 0.0, -50.0, 0.2))
    assert np.allclose(p.pushes[0].impulse, [17.0, 0.0])
    assert (p.mass_scale, p.torso_mass_scale, p.torso_com_offset) == (1.1, 0.9, -0.02)
    assert (p.friction, p.latency_ticks, p.sensor_noise, p.seed) == (0.5, 2, True, 7)


@pytest.mark.parametrize("argv, option", [
    (("--mass-scale", "0"), "--mass-scale"),
    (("--mass-scale", "-1"), "--mass-scale"),
    (("--mass-scale", "nan"), "--mass-scale"),
    (("--mass-scale", "inf"), "--mass-scale"),
    (("--torso-mass-scale", "0"), "--torso-mass-scale"),
    (("--torso-mass-scale", "nan"), "--torso-mass-scale"),
    (("--torso-com-offset", "nan"), "--torso-com-offset"),
    (("--torso-com-offset", "0.2"), "--torso-com-offset"),
    (("--friction", "0"), "--friction"),
    (("--friction", "-0.5"), "--friction"),
    (("--friction", "nan"), "--friction"),
    (("--friction", "2"), "--friction"),
    (("--latency", "-1"), "--latency"),
    (("--push", "3.4", "10", "0", "0"), "--push"),
    (("--push", "3.4", "10", "0", "-0.1"), "--push"),
    (("--push", "nan", "10", "0", "0.1"), "--push"),
    (("--push", "3.4", "nan", "0", "0.1"), "--push"),
    (("--push", "3.4", "10", "inf", "0.1"), "--push"),
    (("--push", "3.4", "10", "0", "nan"), "--push"),
    (("--seed", "-3"), "--seed"),
])
def test_meaningless_values_name_their_option(argv, option):
    with pytest.raises(ValueError, match=option):
        _parse(*argv)


def test_direct_construction_validates_too():
    with pytest.raises(ValueError, match="--latency"):
        Perturbations(latency_ticks=1.5)
    with pytest.raises(ValueError, match="--seed"):
        Perturbations(seed=0.5)
    with pytest.raises(ValueError, match="--push"):
        Perturbations(pushes=((1.0, 10.0, 0.0, 0.0),))
    assert Perturbations(pushes=((1.0, 10.0, 0.0, 0.1),)).pushes[0] == Push(1.0, 10.0, 0.0, 0.1)


# --------------------------------------------------------------------------
# Model errors.


@pytest.fixture(scope="module")
def humanoid():
    builder = DiagramBuilder()
    plant, scene_graph, instance, _ = add_physics_plant(builder, PhysicsParameters())
    return plant


def test_mass_scale_scales_total_mass_keeps_com(humanoid):
    plant = humanoid
    context = plant.CreateDefaultContext()
    m0, c0 = plant.CalcTotalMass(context), plant.CalcCenterOfMassPositionInWorld(context)
    changed = apply_model_errors(plant, context, Perturbations(mass_scale=1.1))
    assert len(changed) > 30
    assert plant.CalcTotalMass(context) == pytest.approx(1.1 * m0, rel=1e-12)
    assert np.allclose(plant.CalcCenterOfMassPositionInWorld(context), c0, atol=1e-12)
    # the plant's defaults (the controller's nominal model) are untouched
    assert plant.CalcTotalMass(plant.CreateDefaultContext()) == pytest.approx(m0, rel=1e-12)


def test_torso_mass_and_com_offset(humanoid):
    plant = humanoid
    torso = plant.GetBodyByName(TORSO)
    context = plant.CreateDefaultContext()
    m0, c0 = plant.CalcTotalMass(context), plant.CalcCenterOfMassPositionInWorld(context)
    mt = torso.default_mass()
    R_WT = plant.EvalBodyPoseInWorld(context, torso).rotation().matrix()
    apply_model_errors(plant, context, Perturbations(torso_mass_scale=1.2, torso_com_offset=0.02))
    m1 = plant.CalcTotalMass(context)
    assert m1 == pytest.approx(m0 + 0.2 * mt, rel=1e-12)
    # new COM: old mass-weighted sum, plus the extra torso mass at its moved COM and the old torso mass moved
    p_t = plant.EvalBodyPoseInWorld(context, torso).multiply(torso.default_com())
    shift = R_WT @ np.array([0.02, 0.0, 0.0])
    expected = (m0 * c0 + 0.2 * mt * p_t + 1.2 * mt * shift) / m1
    assert np.allclose(plant.CalcCenterOfMassPositionInWorld(context), expected, atol=1e-12)
    assert plant.CalcCenterOfMassPositionInWorld(context)[0] > c0[0]  # forward
    assert torso.CalcSpatialInertiaInBodyFrame(context).get_com()[0] == pytest.approx(torso.default_com()[0] + 0.02)


# --------------------------------------------------------------------------
# Friction.


def test_ground_friction_realises_the_effective_dynamic_coefficient():
    params = PhysicsParameters()
    assert ground_friction(Perturbations(), params) is params
    for mu in (0.3, 0.5, 0.8, 1.2):
        g = ground_friction(Perturbations(friction=mu), params)
        combined = CalcContactFrictionFromSurfaceProperties(
            CoulombFriction(g.mu_static, g.mu_dynamic), CoulombFriction(SOLE_MU_STATIC, SOLE_MU_DYNAMIC))
        assert combined.dynamic_friction() == pytest.approx(mu, rel=1e-12)
    assert ground_friction(Perturbations(friction=0.8), params).mu_dynamic == pytest.approx(0.8)


def test_model_soles_have_the_assumed_friction(humanoid):
    from pydrake.geometry import Role
    builder = DiagramBuilder()
    plant, scene_graph, _, ground_id = add_physics_plant(builder, PhysicsParameters())
    inspector = scene_graph.model_inspector()
    seen = 0
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        if gid == ground_id:
            continue
        friction = inspector.GetProximityProperties(gid).GetProperty("material", "coulomb_friction")
        assert (friction.static_friction(), friction.dynamic_friction()) == (SOLE_MU_STATIC, SOLE_MU_DYNAMIC)
        seen += 1
    assert seen >= 8


# --------------------------------------------------------------------------
# Pushes.


def test_pelvis_push_output_in_isolation(humanoid):
    plant = humanoid
    push = PelvisPush(plant=plant, pushes=[Push(0.1, 30.0, -20.0, 0.05), Push(0.12, 5.0, 0.0, 0.01)])
    context = push.CreateDefaultContext()
    pelvis = plant.GetBodyByName(FLOATING_BASE)
    for t, count in ((0.0, 0), (0.1, 1), (0.125, 2), (0.14, 1), (0.15, 0)):
        context.SetTime(t)
        forces = push.applied_spatial_force_port.Eval(context)
        assert len(forces) == count
        for f in forces:
            assert f.body_index == pelvis.index()
            assert np.allclose(f.p_BoBq_B, pelvis.default_com())
            assert np.allclose(f.F_Bq_W.rotational(), 0.0)
    context.SetTime(0.125)
    total = sum(f.F_Bq_W.translational() for f in push.applied_spatial_force_port.Eval(context))
    assert np.allclose(total, [35.0, -20.0, 0.0])


def test_push_through_applied_spatial_force_changes_com_velocity_by_impulse_over_mass():
    """The humanoid high in the air (servos holding its posture): Delta v_COM = impulse / total mass."""
    builder = DiagramBuilder()
    plant, _, instance, _ = add_physics_plant(builder, PhysicsParameters())
    push = Push(0.02, 120.0, -60.0, 0.1)  # 12 N s forward, 6 N s to the right
    system = add_pelvis_push(builder, plant, [push])
    assert plant.get_applied_spatial_force_input_port().GetFullDescription()
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    q = plant.GetPositions(plant_context)
    q[6] = 5.0  # pelvis 5 m up: no contact during the test
    plant.SetPositions(plant_context, q)
    q_idx, _ = actuated_indices(plant)
    plant.get_desired_state_input_port(instance).FixValue(
        plant_context, np.concatenate([q[q_idx], np.zeros(len(q_idx))]))
    mass = plant.CalcTotalMass(plant_context)
    v0 = plant.CalcCenterOfMassTranslationalVelocityInWorld(plant_context)
    simulator.AdvanceTo(0.15)
    v1 = plant.CalcCenterOfMassTranslationalVelocityInWorld(plant_context)
    dv = (v1 - v0)[:2]
    expected = push.impulse / mass
    assert np.allclose(dv, expected, rtol=1e-3, atol=1e-5), (dv, expected)
    assert system.force_at(0.05)[0] == 120.0


def test_friction_reaches_the_ground_geometry():
    params = ground_friction(Perturbations(friction=0.5), PhysicsParameters())
    builder = DiagramBuilder()
    plant, scene_graph, _, ground_id = add_physics_plant(builder, params)
    ground = scene_graph.model_inspector().GetProximityProperties(ground_id).GetProperty(
        "material", "coulomb_friction")
    combined = CalcContactFrictionFromSurfaceProperties(ground, CoulombFriction(SOLE_MU_STATIC, SOLE_MU_DYNAMIC))
    assert combined.dynamic_friction() == pytest.approx(0.5)


# --------------------------------------------------------------------------
# The floor's drop.


def test_floor_drop_option_and_its_errors():
    drop = _parse("--floor-drop", "0.7", "1.1", "-0.2", "0.0", "0.01").floor_drop
    assert drop == FloorDrop(0.7, 1.1, -0.2, 0.0, 0.01)
    assert drop.contains((0.9, -0.1)) and not drop.contains((0.9, 0.1))
    assert _parse().floor_drop is None
    assert Perturbations(floor_drop=(0.7, 1.1, -0.2, 0.0, 0.01)).floor_drop == drop  # a sequence is converted
    assert Perturbations(floor_drop=drop).summary()["floor_drop"] == [0.7, 1.1, -0.2, 0.0, 0.01]
    for values in ((0.7, 1.1, -0.2, 0.0, 0.0), (0.7, 1.1, -0.2, 0.0, -0.01), (0.7, 1.1, -0.2, 0.0, 0.2),
                   (1.1, 0.7, -0.2, 0.0, 0.01), (0.7, 1.1, 0.0, 0.0, 0.01), (0.7, np.nan, -0.2, 0.0, 0.01)):
        with pytest.raises(ValueError, match="--floor-drop"):
            FloorDrop(*values)


def test_perturbed_ground_carries_friction_and_drop():
    params = PhysicsParameters()
    assert perturbed_ground(Perturbations(), params) is params
    drop = FloorDrop(0.7, 1.1, -0.2, 0.0, 0.01)
    ground = perturbed_ground(Perturbations(friction=0.5, floor_drop=drop), params)
    assert ground.floor_drop == drop
    assert ground.mu_dynamic == ground_friction(Perturbations(friction=0.5), params).mu_dynamic
    with pytest.raises(ValueError, match="floor_drop"):
        PhysicsParameters(floor_drop=(0.7, 1.1, -0.2, 0.0, 0.01))


def _sole_clearances(drop):
    """The soles' positions, each sole's contact geometries' signed distances to the nearest ground [m]
    (``{body: [distance]}``), the robot at its zero posture with its lower sole on z = 0, and the world's
    ground geometries."""
    from pydrake.math import RigidTransform

    from drake_estop.physics.plant import _base_height_at_zero, ground_geometries, sole_frames
    from drake_estop.robots.parameters import as_robot
    builder = DiagramBuilder()
    plant, scene_graph, _, _ = add_physics_plant(builder, PhysicsParameters(floor_drop=drop))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    description = as_robot(None)
    base = plant.GetBodyByName(description.floating_base)
    plant.SetFreeBodyPose(plant_context, base, RigidTransform([0.0, 0.0, _base_height_at_zero(description)]))
    soles = [frame.CalcPoseInWorld(plant_context).translation() for frame in sole_frames(plant)]
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    ground = set(ground_geometries(plant))
    nearest = {}
    for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=0.05):
        ids = {pair.id_A, pair.id_B}
        if len(ids & ground) != 1:
            continue
        geometry = next(iter(ids - ground))
        nearest[geometry] = min(nearest.get(geometry, np.inf), pair.distance)
    by_body = {}
    for geometry, distance in nearest.items():
        by_body.setdefault(plant.GetBodyFromFrameId(inspector.GetFrameId(geometry)).name(), []).append(distance)
    return soles, {body: sorted(values) for body, values in by_body.items()}, ground


def test_floor_drop_lowers_the_floor_under_its_rectangle_only():
    """A sole over the drop is ``depth`` farther from the ground than one beside it, and the soles' contact
    geometry is filtered against every ground geometry alike (the corner spheres only)."""
    flat_soles, flat, flat_ground = _sole_clearances(None)
    assert len(flat_ground) == 1
    right = flat_soles[1]
    # the right sole's corners over the drop (its inner edge 5 mm from the middle), the left's beside it
    drop = FloorDrop(right[0] - 0.2, right[0] + 0.2, right[1] - 0.1, 0.0, 0.01)
    soles, dropped, ground = _sole_clearances(drop)
    assert len(ground) == 5
    assert not drop.contains(soles[0][:2]) and drop.contains(soles[1][:2])
    assert sorted(flat) == sorted(dropped) == ["l_sole", "r_sole"]  # nothing else near the floor
    assert len(flat["r_sole"]) == 4 and np.allclose(flat["r_sole"], flat["l_sole"], atol=1e-12)  # corner spheres
    assert np.allclose(dropped["l_sole"], flat["l_sole"], atol=1e-12)
    # the outer corners over the lowered half-space, the inner ones 5 mm from the drop's edge (nearer to it)
    gaps = np.array(dropped["r_sole"]) - np.array(flat["r_sole"])
    assert gaps.max() == pytest.approx(0.01, abs=1e-9) and np.all(gaps > 0.005)
