"""The walk's COG moved so that the whole body's ZMP, not the pendulum's, is the one planned.

The nominal pattern (:class:`~drake_estop.planning.gait.NominalPattern`) plans its COG on the LIPM (eq. 4).
Through the whole-body IK the limbs move besides, and the ZMP the floor must carry
(:func:`~drake_estop.systems.multibody_zmp.multibody_zmp`) leaves the plan's: on the G1 (legs 43 % of its
mass, 0.27 m steps in 0.63 s) by up to 74 mm, 14 mm behind the stance heel late in its second step. The
compensation of Kajita et al. (2003, the preview control's second stage) moves the COG by the LIPM's answer
to the opposite shift (:func:`~drake_estop.planning.com_correction.lipm_correction`), rolls the corrected
walk through the IK again and repeats: each pass leaves the shift the last one's COG change made.

The stop planner starts from the corrected walk's COG (its position and velocity at the signal) and plans
the stop on the LIPM as before: the correction covers the walk, not the stop.

Measured through the kinematic diagram (``benchmarks/bench_robots.py``), the walk's whole-body ZMP off the
plan at most: G1 74 -> 4.0 mm (its least margin in the soles -14.2 -> +16.8 mm), the default humanoid
75 -> 4.0 mm, TALOS 85 -> 5.3 mm. In physics (the online controller, ``ControllerOptions(whole_body_walk=
True)``): on 70 hard runs of the default humanoid's campaign 35 stop (33 on the LIPM's COG) and 6 fall (11);
the perturbation matrix 43/44 (44/44), the 17 N s push to the right early in single support falling.
The G1's single support then tracks (its CoP 3 mm behind the plan's ZMP, not 37 mm on the heel; torso tilt
5 mrad, not 13). With the feet's force control (8000 N s/m) and a 10 mrad swing-tilt dead band its own
0.79 s walk stands and stops from double support and from single support late in the walk; at its 2 mrad
dead band the swing foot struck the floor 30 ms early and bounced (a fall at 2.5 s), and on the LIPM's COG
it falls in the walk whatever the dead band. Its third step's single-support stops still fail by a
millimetre of CoP or a bounce at the landing: the stop is not corrected.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from drake_estop.planning.com_correction import lipm_correction
from drake_estop.planning.gait import NominalPattern
from drake_estop.robots.parameters import as_robot, gait_parameters

#: Passes of the compensation: measured on the G1's walk the largest shift goes 74 -> 12 -> 3.5 mm in two;
#: a third left it at 3-7 mm (the 50 ms averaging of the landings' transients, not the COG, sets that floor).
DEFAULT_PASSES = 2


@dataclass(frozen=True)
class WalkZmpShift:
    """The whole body's ZMP on the IK's joint trajectory of a walk without a stop, against the plan's:
    ``times`` (n,) [s], ``shift`` (n, 2) whole-body less planned ZMP [m], ``margin`` (n,) distance of the
    whole-body ZMP inside the soles on the floor [m] (negative outside, NaN with no sole down)."""

    times: np.ndarray
    shift: np.ndarray
    margin: np.ndarray

    @property
    def largest(self) -> float:
        """The largest shift [m] (either axis)."""
        return float(np.abs(self.shift).max())

    @property
    def least_margin(self) -> float:
        """The least margin [m] over the walk."""
        return float(np.nanmin(self.margin))


def walk_zmp_shift(pattern: NominalPattern, robot=None) -> WalkZmpShift:
    """Roll ``pattern`` (no stop signal) through ``robot``'s kinematic diagram and measure its whole-body ZMP
    against the planned one (:class:`WalkZmpShift`)."""
    from drake_estop.systems.diagram import build_diagram, collect_result, run

    handles = build_diagram(robot=robot, pattern=pattern, estop_time=None)
    simulator, wall = run(handles, after_halt=0.5)
    result = collect_result(handles, simulator.get_context(), wall_time=wall)  # result.zmp: the walk's, planned
    return WalkZmpShift(result.times, result.multibody_zmp - result.zmp, result.multibody_zmp_margin)


@dataclass(frozen=True)
class CorrectedWalk:
    """A walk corrected for the limbs' momentum: its ``pattern`` and the shift of the LIPM's walk its first
    pass measured (``lipm_shift``, :class:`WalkZmpShift`)."""

    pattern: NominalPattern
    lipm_shift: WalkZmpShift


def corrected_walk(robot=None, gait_params=None, *, passes: int = DEFAULT_PASSES) -> CorrectedWalk:
    """``robot``'s walk (``gait_params``, default its own gait) with the COG corrected in ``passes`` rounds so
    that the whole body's ZMP is the planned one (the module docstring), and what the first round measured
    on the LIPM's walk. The IK rolls the walk out once a pass (2-3 s each on the default humanoid, 4-5 s on
    the G1); a process keeps the last few (the pattern is not changed after it is built)."""
    if isinstance(passes, bool) or not isinstance(passes, int) or passes < 1:
        raise ValueError(f"passes must be a positive integer, got {passes!r}")
    robot = as_robot(robot)
    return _corrected(robot, gait_params or gait_parameters(robot), passes)


def whole_body_pattern(robot=None, gait_params=None, *, passes: int = DEFAULT_PASSES) -> NominalPattern:
    """The pattern of :func:`corrected_walk`."""
    return corrected_walk(robot, gait_params, passes=passes).pattern


@functools.lru_cache(maxsize=4)
def _corrected(robot, gait_params, passes: int) -> CorrectedWalk:
    pattern = NominalPattern(gait_params)
    correction, first = None, None
    for _ in range(passes):
        measured = walk_zmp_shift(pattern, robot)
        first = measured if first is None else first
        step = lipm_correction(measured.times, measured.shift, pattern.w)
        correction = step if correction is None else correction + step
        pattern = NominalPattern(gait_params, com_correction=correction)
    return CorrectedWalk(pattern, first)


__all__ = ["DEFAULT_PASSES", "CorrectedWalk", "WalkZmpShift", "corrected_walk", "walk_zmp_shift",
           "whole_body_pattern"]
