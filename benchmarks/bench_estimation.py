"""State-estimator accuracy and per-tick cost against the simulated truth.

Imports the installed package (``pip install -e .``, or PYTHONPATH=. from the repository).

    python benchmarks/bench_estimation.py            # standing + push (about 30 s)
    python benchmarks/bench_estimation.py --walk     # + a 3.3 s walk of the online controller (about 1 min)

Standing: the humanoid on the contact plant (``physics.add_physics_plant``),
PD servos holding ``nominal_standing_configuration``, the estimator open loop
(``estimation.add_state_estimation``), 2 s. Push: 170 N forward on the pelvis
for 0.1 s at 0.3 s (17 N s), errors during the push and in the 0.1 s after.
Walk: the online controller's diagram (``online.build_online_diagram``, no
stop; its own estimator feeds the planner) with further estimator variants
attached open loop through a DiagramBuilder hook. Truth: the COG of the simulated
plant (its context's parameters) from the logged state.

Errors are the norm of the COG error (3D) and of the horizontal COG-velocity
error, RMS / max over the 5 ms log; noise with seed 1. Cost: the estimator's
own CPU time per tick (``time.thread_time`` around its step with the inputs
already evaluated), and the same including the sensors and the CoP
estimator upstream.

Measured 2026-11-25 (2 cores shared, load ~4):

    standing, no noise         COG 0.15 / 0.17 mm   vel 0.2 / 0.8 mm/s
    standing, noise            COG 1.10 / 1.96 mm   vel 4.9 / 11.3 mm/s
    standing, latency 1        COG 0.15 / 0.18 mm   vel 0.1 / 0.8 mm/s
    standing, mass x1.1        COG 0.16 / 0.19 mm   vel 0.2 / 0.8 mm/s
    standing, torso COM +2 cm  COG 6.48 / 6.51 mm   (model error: the estimator keeps the nominal model)
    walk, no noise (hybrid)    COG 0.97 / 2.25 mm   vel 4.8 / 11.6 mm/s
    walk, noise (hybrid)       COG 1.89 / 4.22 mm   vel 6.7 / 18.6 mm/s
    cost: estimator CPU median 0.19-0.26 ms, p99 0.37-0.63 ms, max <= 0.97 ms;
          with sensors + CoP upstream median 0.58-0.74 ms, p99 <= 1.42 ms, max <= 1.94 ms
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from drake_estop.model import LEFT_SOLE, RIGHT_SOLE, nominal_standing_configuration
from drake_estop.physics import estimation, online
from drake_estop.physics import plant as physics
from drake_estop.physics.perturbations import Perturbations, Push, add_pelvis_push, apply_model_errors
from drake_estop.systems.ik import shared_ik

DT = 0.005


class _Timer:
    """Per-tick CPU time of StateEstimator._step (inputs evaluated first, so upstream work is separate)."""

    def __init__(self):
        self.own, self.total = [], []
        self._orig = estimation.StateEstimator._step
        timer = self

        def timed(system, context, t_and_more_x, *rest):
            start = time.thread_time()
            for port in (system.encoders_port, system.gyro_port, system.accelerometer_port,
                         system.foot_forces_port, system.cop_port, system.wrench_port):
                port.Eval(context)
            mid = time.thread_time()
            result = timer._orig(system, context, t_and_more_x, *rest)
            end = time.thread_time()
            timer.own.append(end - mid)
            timer.total.append(end - start)
            return result
        estimation.StateEstimator._step = timed

    def restore(self):
        estimation.StateEstimator._step = self._orig

    @staticmethod
    def stats(values):
        v = np.array(values) * 1e3
        return f"median {np.median(v):.3f} p99 {np.percentile(v, 99):.3f} max {v.max():.3f} ms"


def _truth(plant, perturbations, states):
    context = plant.CreateDefaultContext()
    apply_model_errors(plant, context, perturbations)
    com, vel = [], []
    for x in states:
        plant.SetPositionsAndVelocities(context, x)
        com.append(plant.CalcCenterOfMassPositionInWorld(context))
        vel.append(plant.CalcCenterOfMassTranslationalVelocityInWorld(context))
    return np.array(com), np.array(vel)


def _errors(com, vel, true_com, true_vel, mask=None):
    n = min(len(com), len(true_com))
    ec = np.linalg.norm(com[:n] - true_com[:n], axis=1)
    ev = np.linalg.norm((vel[:n] - true_vel[:n])[:, :2], axis=1)
    if mask is not None:
        ec, ev = ec[mask[:n]], ev[mask[:n]]
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    return (f"COG {rms(ec) * 1e3:5.2f} / {ec.max() * 1e3:5.2f} mm   "
            f"vel {rms(ev) * 1e3:5.1f} / {ev.max() * 1e3:5.1f} mm/s")


def standing(perturbations, duration=2.0, pushes=(), **options):
    builder = DiagramBuilder()
    plant, scene_graph, instance, _ = physics.add_physics_plant(builder, physics.PhysicsParameters())
    soles = [plant.GetBodyByName(n) for n in (LEFT_SOLE, RIGHT_SOLE)]
    cop = builder.AddSystem(physics.CopEstimator(plant=plant, scene_graph=scene_graph, bodies=soles))
    builder.Connect(plant.get_contact_results_output_port(), cop.contact_results_port)
    q0 = nominal_standing_configuration(plant)
    physics.add_pose_hold(builder, plant, instance, q0)
    add_pelvis_push(builder, plant, pushes)
    estimator = estimation.add_state_estimation(builder, plant, cop, servo_period=DT, perturbations=perturbations,
                                                initial_q=q0, **options)
    logs = [LogVectorOutput(p, builder, DT) for p in (plant.get_state_output_port(), estimator.com_port,
                                                      estimator.com_vel_port)]
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    plant.SetPositions(plant_context, q0)
    apply_model_errors(plant, plant_context, perturbations)
    simulator.AdvanceTo(duration)
    states, com, vel = (log.FindLog(context).data().T for log in logs)
    return (com, vel) + _truth(plant, perturbations, states)


def walk(variants, duration=3.3):
    from drake_estop.planning.gait import NominalPattern
    from drake_estop.systems.diagram import initial_configuration

    pattern = NominalPattern()
    kin_plant, _, _ = shared_ik()
    q0 = initial_configuration(kin_plant, pattern)
    logs = {}

    def attach(builder):  # the estimators, before the online diagram is built
        plant = next(s for s in builder.GetSystems() if s.get_name() == "plant")
        cop = next(s for s in builder.GetSystems() if isinstance(s, physics.CopEstimator))
        for name, (perturbations, options) in variants.items():
            est = estimation.add_state_estimation(builder, plant, cop, servo_period=DT, perturbations=perturbations,
                                                  initial_q=q0, name_prefix=name + "_", **options)
            logs[name] = (LogVectorOutput(est.com_port, builder, DT), LogVectorOutput(est.com_vel_port, builder, DT))

    handles, context = _walk(pattern, attach, duration)
    true_com, true_vel = _truth(handles.plant, Perturbations(),
                                handles.loggers["state"].FindLog(context).data().T)
    for name, (com_log, vel_log) in logs.items():
        com, vel = com_log.FindLog(context).data().T, vel_log.FindLog(context).data().T
        print(f"  walk {name:22s} {_errors(com, vel, true_com, true_vel)}")


def _walk(pattern, before_build, duration):
    """Simulate the online controller's diagram (:func:`online.build_online_diagram`, no stop
    signal, the estimate fed back to the planner) for ``duration`` s, with
    ``before_build(builder)`` run on its builder just before it is built. Returns (handles, context)."""
    class Hook(DiagramBuilder):
        def Build(self):
            before_build(self)
            return super().Build()

    original = online.DiagramBuilder
    online.DiagramBuilder = Hook
    try:
        handles = online.build_online_diagram(pattern, online.controller_stop_parameters(), None)
    finally:
        online.DiagramBuilder = original
    simulator = online.online_simulator(handles)
    context = simulator.get_mutable_context()
    simulator.AdvanceTo(duration)
    return handles, context


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--walk", action="store_true", help="also the 3.3 s walk of the online controller")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")
    timer = _Timer()
    try:
        for label, perturbations in (("no noise", Perturbations()),
                                     ("noise", Perturbations(sensor_noise=True, seed=1)),
                                     ("latency 1", Perturbations(latency_ticks=1)),
                                     ("mass x1.1", Perturbations(mass_scale=1.1)),
                                     ("torso COM +2 cm", Perturbations(torso_com_offset=0.02))):
            print(f"  standing, {label:16s} {_errors(*standing(perturbations))}")
        print(f"  cost: estimator CPU {timer.stats(timer.own)}; with sensors + CoP upstream {timer.stats(timer.total)}")
    finally:
        timer.restore()
    push = [Push(0.3, 170.0, 0.0, 0.1)]
    for model in ("force", "imu", "hybrid", "lipm"):
        com, vel, true_com, true_vel = standing(Perturbations(), duration=0.6, pushes=push, model=model)
        t = DT * np.arange(len(true_com))
        during = _errors(com, vel, true_com, true_vel, (t >= 0.3) & (t < 0.4))
        after = _errors(com, vel, true_com, true_vel, (t >= 0.4) & (t < 0.5))
        print(f"  17 N s push, {model:6s} during: {during}   after: {after}")
    if args.walk:
        variants = {}
        for noise in (False, True):
            for model in ("force", "imu", "hybrid", "lipm"):
                variants[f"{model}_noise{int(noise)}"] = (Perturbations(sensor_noise=noise, seed=1), dict(model=model))
        walk(variants)


if __name__ == "__main__":
    main()
