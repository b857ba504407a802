"""What the robot can catch: N-step capturability of the LIPM with finite feet (Koolen et al. 2012).

A state is *N-step capturable* when some sequence of at most N steps, each landing
where the legs reach and no sooner than the swing can touch down, brings the
divergent component of motion (DCM, ``xi = x + x' / omega``, eq. 4 and 6-9) inside
the last stance sole, where the ankle holds it and the COG comes to rest
(Koolen, de Boer, Rebula, Goswami, Pratt, "Capturability-based analysis and
control of legged locomotion, Part 1", IJRR 2012; Pratt et al. 2006).

**Conservative after a landing.** That is Koolen's definition, with single support
at the end. A stop ends in double support, where a DCM anywhere in the hull of
both soles can be held; the verdict does not count a DCM left between the feet
after the last landing, so it may call a state uncapturable that a stop catches.
On the seed-0 campaign 4 of the 6 runs it calls so met every criterion (run 252:
the DCM 2 cm inside of the narrowest landing's inner edge, between the feet).

**The recursion.** With the CoP ``u`` constant in the stance sole over a step of
duration ``T`` (the LIPM is linear, so a varying CoP in a convex sole reaches no
other DCM), ``xi(T) = u + (xi(0) - u) exp(omega T)``. Backwards, with
``b = exp(-omega T)``, the set the DCM may start from, in the stance ankle's
frame, is the Minkowski sum

    C_k = (1 - b) U_k + b (S_k + C_{k+1}),    C_N = U_N,

with ``U_k`` the CoP rectangle of the k-th stance sole and ``S_k`` the region
where the next foot may land relative to its ankle. Soles and landing regions
are rectangles in the walking heading's frame (sagittal x, lateral y), so the
recursion is interval arithmetic on each axis, the two axes sharing the step
times. Steps alternate feet; a region given for the left foot landing from a
right stance is mirrored for the other. With a point foot and one sagittal
region ``[-l, l]`` it is Koolen's closed form
``d_N = r + l (b + b^2 + ... + b^N)`` (``r`` the sole's half length).

**The regions** (:class:`SteppingLimits`, from a robot's stop limits by
:meth:`SteppingLimits.from_parameters`):

* ``nominal``: beside the stance foot, ``min_step_width`` to ``max_step_width``
  ankle to ankle, from ``backward`` behind to ``forward`` ahead;
* ``crossover ahead`` / ``crossover behind``: in line with the stance foot up to
  ``crossover_reach`` past its ankle, the soles ``crossover_gap`` clear of each
  other sagittally (the landing heel past the stance toe, or the landing toe
  behind the stance heel). ``crossover_reach = 0`` switches them off.

The legs' own collision geometry is not in these regions: a crossover the support
knee bars (:mod:`drake_estop.planning.crossover` measures the default humanoid's)
is counted as reachable here, so the verdict is an upper bound where crossovers
count, and the table switches them off to show both.

**Step times.** The first landing comes no sooner than ``first_step_time`` (the
swing's least time to touch down from where it is), every later one no sooner
than ``min_step_time`` (a weight shift and a whole swing), none later than
``max_step_time``; the times are searched on a grid of :data:`TIME_SAMPLES` per
step, evenly in ``b``, the shortest included (stepping soonest is what catches
most). A state is captured by at most :data:`MAX_STEPS` steps.

**The margin** is the DCM's signed distance [m] to the boundary of the region
captured in the least number of steps (positive inside; where nothing captures,
minus the distance to the N = :data:`MAX_STEPS` region), and ``omega`` times it
as a push speed [m/s]: an impulsive push changes the DCM by ``dv / omega``. The
region is a union of rectangles (one per choice of regions and times); inside,
the margin is the depth in the deepest one, a lower bound of the depth in the
union. In double support the 0-step region is the convex hull of both soles'
CoP rectangles, and either foot may step first.

Pure numpy: it is evaluated at every servo tick (:func:`capturability`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from drake_estop.planning.gait import Sole
from drake_estop.planning.geometry import convex_hull

#: Most steps the verdict looks ahead: a third step adds almost nothing laterally (the trailing foot
#: cannot pass the leading one without another crossover), and the stop plans at most three landings.
MAX_STEPS = 3
#: Step times searched per step, evenly in exp(-omega T) from the shortest to the longest.
TIME_SAMPLES = 5


@dataclass(frozen=True)
class SteppingLimits:
    """Where and when a foot can land, for the capturability verdict.

    Landing regions are given for the left foot landing from a right stance, in
    the stance sole's frame (x ahead, y to the left); the right foot's are their
    mirror image.

    Attributes
    ----------
    sole : Sole
        Both soles' rectangle about the ankle.
    cop_margin : float
        Shrinks each sole's CoP rectangle [m].
    forward, backward : float
        Farthest landing ankle ahead of and behind the stance ankle [m].
    min_width, max_width : float
        Nearest and farthest landing beside the stance ankle, ankle to ankle [m].
    crossover_reach : float
        Farthest crossover landing past the stance ankle [m] (0: no crossover regions).
    crossover_gap : float
        Sagittal gap between the soles of a crossover landing [m].
    min_step_time, max_step_time : float
        Shortest step after the first (a weight shift and a swing) and longest step [s].
    swing_speed : float
        The first landing lies within this times its step time of the swing foot on each axis [m/s].
    """

    sole: Sole = field(default_factory=Sole)
    cop_margin: float = 0.0
    forward: float = 0.4
    backward: float = 0.26
    min_width: float = 0.15
    max_width: float = 0.30
    crossover_reach: float = 0.10
    crossover_gap: float = 0.01
    min_step_time: float = 0.3
    max_step_time: float = 1.0
    swing_speed: float = 1.12

    def __post_init__(self):
        for name in ("forward", "backward", "max_width", "crossover_reach", "crossover_gap", "cop_margin",
                     "swing_speed"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"SteppingLimits.{name} must be finite and >= 0, got {value!r}")
        if not (math.isfinite(self.min_width) and self.min_width <= self.max_width):
            raise ValueError(f"SteppingLimits.min_width must be finite and <= max_width, got {self.min_width!r}")
        if not (0.0 < self.min_step_time <= self.max_step_time < math.inf):
            raise ValueError("SteppingLimits needs 0 < min_step_time <= max_step_time < inf, got "
                             f"{self.min_step_time!r}, {self.max_step_time!r}")
        half_length, half_width = (self.sole.toe + self.sole.heel) / 2, (self.sole.inner + self.sole.outer) / 2
        if self.cop_margin > min(half_length, half_width):
            raise ValueError(f"SteppingLimits.cop_margin {self.cop_margin!r} leaves no CoP in the sole")

    @classmethod
    def from_parameters(cls, params, sole: Sole | None = None, **changes) -> SteppingLimits:
        """The limits of a robot's stop (:class:`~drake_estop.planning.plan.StopParameters`): its longest
        step ahead, its rear reach behind, its landing widths and longest landing, on ``sole`` (the
        default humanoid's when None); ``changes`` override any field."""
        values = dict(forward=params.max_step_length, backward=params.max_rear_reach,
                      min_width=params.min_step_width, max_width=params.max_step_width,
                      max_step_time=params.max_landing_time, swing_speed=params.max_swing_speed,
                      sole=sole or Sole())
        values.update(changes)
        return cls(**values)

    def cop_box(self, side: str) -> np.ndarray:
        """The CoP rectangle of the ``side`` foot's sole about its ankle: ``[[x_lo, x_hi], [y_lo, y_hi]]``."""
        left, right = self.sole.lateral_edges(side)
        m = self.cop_margin
        return np.array([[-self.sole.heel + m, self.sole.toe - m], [-right + m, left - m]])

    def regions(self, side: str) -> dict:
        """The non-empty landing regions of the ``side`` foot about the other (stance) foot's ankle: name ->
        ``[[x_lo, x_hi], [y_lo, y_hi]]``."""
        clear = self.sole.toe + self.sole.heel + self.crossover_gap  # sagittal, ankle to ankle
        boxes = {"nominal": [[-self.backward, self.forward], [self.min_width, self.max_width]]}
        if self.crossover_reach > 0.0:
            lateral = [-self.crossover_reach, self.min_width]
            boxes["crossover ahead"] = [[clear, self.forward], lateral]
            boxes["crossover behind"] = [[-self.backward, -clear], lateral]
        out = {}
        for name, box in boxes.items():
            box = np.array(box, dtype=float)
            if side == "right":
                box[1] = -box[1][::-1]
            if np.all(box[:, 0] <= box[:, 1]):
                out[name] = box
        return out


@dataclass(frozen=True)
class CaptureStep:
    """One landing of a witness: the ``side`` foot lands in ``region`` at ``landing`` (world xy [m]),
    ``time`` [s] after the state's, and holds the CoP at ``cop`` (world xy [m]) until the next."""

    side: str
    region: str
    landing: tuple
    time: float
    cop: tuple


@dataclass(frozen=True)
class Capturability:
    """The verdict on one state.

    Attributes
    ----------
    steps : int
        The least N <= :data:`MAX_STEPS` that captures it; -1: none (dimensionless).
    margin : float
        The DCM's signed distance to that capture region's boundary [m] (module docstring; negative outside).
    margin_speed : float
        ``omega * margin`` [m/s]: the impulsive push speed that margin stands for.
    witness : tuple of CaptureStep
        The steps of a sequence that captures it (empty for N = 0 or none).
    """

    steps: int
    margin: float
    margin_speed: float
    witness: tuple = ()

    def __deepcopy__(self, memo):  # immutable through and through: Drake's state clones share it
        return self

    @property
    def capturable(self) -> bool:
        return self.steps >= 0

    def as_dict(self) -> dict:
        """JSON-ready: ``{steps, margin, margin_speed, witness: [{side, region, landing, time, cop}]}``."""
        return {"steps": self.steps, "margin": self.margin, "margin_speed": self.margin_speed,
                "witness": [{"side": s.side, "region": s.region, "landing": [float(v) for v in s.landing],
                             "time": s.time, "cop": [float(v) for v in s.cop]} for s in self.witness]}


def _other(side: str) -> str:
    return "left" if side == "right" else "right"


def _box_depth(point: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Signed distance of ``point`` (2,) to each of ``boxes`` (n, 2, 2): positive inside (to the nearest
    edge), negative outside (minus the Euclidean distance)."""
    below, above = boxes[:, :, 0] - point, point - boxes[:, :, 1]
    outside = np.linalg.norm(np.maximum(np.maximum(below, above), 0.0), axis=1)
    inside = np.min(np.minimum(-below, -above), axis=1)
    return np.where(outside > 0.0, -outside, inside)


def _time_grid(omega: float, shortest: float, longest: float) -> np.ndarray:
    """Step times [s] from ``shortest`` to ``longest``, :data:`TIME_SAMPLES` of them evenly in exp(-omega T)."""
    if longest <= shortest:
        return np.array([shortest])
    b = np.linspace(math.exp(-omega * shortest), math.exp(-omega * longest), TIME_SAMPLES)
    return -np.log(b) / omega


class _Sequences:
    """Every choice of regions and step times for ``steps`` steps from a ``stance`` foot: ``options[k]`` the
    (region name, step time, landing rectangle about the stance ankle) choices of step k, ``boxes`` (n, 2, 2)
    the rectangle of DCMs (stance frame) that each sequence captures, sequence ``i`` choosing
    ``np.unravel_index(i, shape)``. With ``swing`` (the swinging foot's xy in the stance frame) the first
    landing also lies within ``limits.swing_speed`` times its step time of it on each axis."""

    def __init__(self, limits: SteppingLimits, omega: float, stance: str, steps: int, first_time: float,
                 swing=None):
        self.sides = [stance if k % 2 == 0 else _other(stance) for k in range(steps + 1)]  # stance feet in order
        if steps == 0:
            self.options, self.shape, self.boxes = [], (), _cop_box(limits, stance)[None]
            return
        tail = _tail(limits, omega, self.sides[1], steps - 1)  # the later steps do not depend on first_time
        shortest = min(max(first_time, 0.0), limits.max_step_time)
        first = []
        for name, region in _regions(limits, self.sides[1]).items():
            for t in _time_grid(omega, shortest, limits.max_step_time):
                box = region
                if swing is not None:  # where the swing gets to in time t (a box about the foot)
                    reach = limits.swing_speed * t
                    box = np.stack([np.maximum(region[:, 0], swing - reach), np.minimum(region[:, 1], swing + reach)],
                                   axis=1)
                if np.all(box[:, 0] <= box[:, 1]):
                    first.append((name, float(t), box))
        self.options, self.shape = [first, *tail.options], (len(first), *tail.shape)
        if not first:
            self.boxes = np.empty((0, 2, 2))
            return
        # the step from this stance onto the other foot, every choice at once (eq. 6-9 backwards)
        b = np.exp(-omega * np.array([t for _, t, _ in first]))[:, None, None, None]
        landing = np.stack([box for _, _, box in first])[:, None]
        self.boxes = ((1.0 - b) * _cop_box(limits, stance) + b * (landing + tail.boxes[None])).reshape(-1, 2, 2)

    def choice(self, index: int) -> list:
        """The (region name, step time, landing rectangle) of each step of sequence ``index``."""
        picks = np.unravel_index(index, self.shape) if self.shape else ()
        return [self.options[k][int(j)] for k, j in enumerate(picks)]

    def chain(self, index: int, limits: SteppingLimits, omega: float) -> list:
        """The rectangles C_0 .. C_N (each about its stance ankle) of sequence ``index``."""
        choice, steps = self.choice(index), len(self.shape)
        chain = [_cop_box(limits, self.sides[steps])]
        for k in reversed(range(steps)):
            _, t, landing = choice[k]
            b = math.exp(-omega * t)
            chain.insert(0, (1.0 - b) * _cop_box(limits, self.sides[k]) + b * (landing + chain[0]))
        return chain


@functools.lru_cache(maxsize=16)
def _regions(limits: SteppingLimits, side: str) -> dict:
    regions = limits.regions(side)
    for box in regions.values():
        box.setflags(write=False)
    return regions


@functools.lru_cache(maxsize=16)
def _cop_box(limits: SteppingLimits, side: str) -> np.ndarray:
    box = limits.cop_box(side)
    box.setflags(write=False)
    return box


@functools.lru_cache(maxsize=64)
def _tail(limits: SteppingLimits, omega: float, stance: str, steps: int) -> _Sequences:
    """The sequences of ``steps`` steps from a foot that has just landed (cached: they do not change)."""
    return _Sequences(limits, omega, stance, steps, limits.min_step_time)


def _witness(dcm_local, sequence: _Sequences, index: int, limits: SteppingLimits, omega: float, ankle, rotation):
    """The landings (world frame) of sequence ``index`` for a DCM ``dcm_local`` (stance frame) inside its
    rectangle: each step's interval sum ``(1 - b) U + b S + b C`` split at one fraction per axis, so that the
    pieces add up to the DCM (module docstring)."""
    chain, steps = sequence.chain(index, limits, omega), []
    position, local_ankle, elapsed = np.asarray(dcm_local, dtype=float), np.zeros(2), 0.0
    for k, (name, duration, landing) in enumerate(sequence.choice(index)):
        b = math.exp(-omega * duration)
        parts = ((1.0 - b) * _cop_box(limits, sequence.sides[k]), b * landing, b * chain[k + 1])
        low, high = sum(p[:, 0] for p in parts), sum(p[:, 1] for p in parts)
        fraction = np.clip((position - low) / np.where(high > low, high - low, 1.0), 0.0, 1.0)
        held, step, rest = (p[:, 0] + fraction * (p[:, 1] - p[:, 0]) for p in parts)
        elapsed += duration
        steps.append(CaptureStep(sequence.sides[k + 1], name, tuple(ankle + rotation @ (local_ankle + step / b)),
                                 elapsed, tuple(ankle + rotation @ (local_ankle + held / (1.0 - b)))))
        position, local_ankle = rest / b, local_ankle + step / b  # the DCM about the new stance ankle
    return tuple(steps)


def _hull_depth(point, corners: np.ndarray) -> float:
    """Signed distance [m] of ``point`` to the convex hull of ``corners`` (n, 2): positive inside (the
    monitor asks every tick: a few corners in plain floats, no qhull set-up)."""
    vertices = convex_hull(corners).tolist()  # counter-clockwise
    px, py = float(point[0]), float(point[1])
    inside, outside = math.inf, math.inf
    for (ax, ay), (bx, by) in zip(vertices, vertices[1:] + vertices[:1]):
        ex, ey = bx - ax, by - ay
        length_sq = ex * ex + ey * ey
        dx, dy = px - ax, py - ay
        inside = min(inside, (dx * ey - dy * ex) / -math.sqrt(length_sq))  # to the edge's line, > 0 inside
        s = min(max((dx * ex + dy * ey) / length_sq, 0.0), 1.0)
        outside = min(outside, math.hypot(dx - s * ex, dy - s * ey))  # to the edge
    return inside if inside >= 0.0 else -outside


def _rotation(heading: float) -> np.ndarray:
    c, s = math.cos(heading), math.sin(heading)
    return np.array([[c, -s], [s, c]])


def _cop_corners(limits: SteppingLimits, side: str, ankle, rotation) -> np.ndarray:
    box = _cop_box(limits, side)
    local = np.array([[box[0, i], box[1, j]] for i in (0, 1) for j in (0, 1)])
    return ankle + local @ rotation.T


def _deepest(dcm, steps: int, stances: list, swings: list, limits: SteppingLimits, omega: float,
             first_step_time: float, rotation) -> tuple:
    """The sequence of ``steps`` steps from any of ``stances`` (``(side, ankle)``, each with its swing foot in
    ``swings``) whose rectangle holds the DCM ``dcm`` (world xy [m]) deepest: ``(depth [m], (sequence, index,
    the DCM in its stance frame, its stance ankle))``, ``(-inf, None)`` where no sequence exists."""
    best = (-math.inf, None)
    for (side, ankle), swing in zip(stances, swings):
        sequence = _Sequences(limits, omega, side, steps, first_step_time,
                              None if swing is None else rotation.T @ (swing - ankle))
        if not len(sequence.boxes):
            continue
        local = rotation.T @ (dcm - ankle)
        depths = _box_depth(local, sequence.boxes)
        index = int(np.argmax(depths))
        if depths[index] > best[0]:
            best = (float(depths[index]), (sequence, index, local, ankle))
    return best


def capturability(dcm, *, omega: float, stance_ankle, stance_side: str, limits: SteppingLimits,
                  first_step_time: float, heading: float = 0.0, other_ankle=None, swing_foot=None,
                  max_steps: int = MAX_STEPS) -> Capturability:
    """The N-step capturability of a state (module docstring).

    Parameters
    ----------
    dcm : array_like
        The DCM ``x + v / omega``, world xy [m].
    omega : float
        The LIPM's natural frequency sqrt(g / z) [1/s].
    stance_ankle : array_like
        The stance foot's ankle, world xy [m].
    stance_side : str
        ``"left"`` or ``"right"``.
    limits : SteppingLimits
        Where and when the feet can land.
    first_step_time : float
        The swing's least time to touch down [s] (in double support, a weight shift and a swing: at least
        ``limits.min_step_time`` is sensible).
    heading : float
        The soles' heading [rad].
    other_ankle : array_like, optional
        The other ankle, world xy [m], where that foot is down too (double support: either foot may step
        first, from its ankle).
    swing_foot : array_like, optional
        Where the swing foot is, world xy [m] (single support): the first landing lies within
        ``limits.swing_speed`` times its step time of it on each axis. None: anywhere in reach.
    max_steps : int
        Look no further than this many steps (0 to :data:`MAX_STEPS`).

    Returns
    -------
    Capturability
        The least N, the margin [m] and [m/s], a witness.

    Raises
    ------
    ValueError
        Naming the argument: a DCM or an ankle not finite, an unknown side, ``omega`` <= 0, ``max_steps`` out
        of range.
    """
    if stance_side not in ("left", "right"):
        raise ValueError(f"stance_side must be 'left' or 'right', got {stance_side!r}")
    if not (math.isfinite(omega) and omega > 0.0):
        raise ValueError(f"omega must be finite and > 0, got {omega!r}")
    if not math.isfinite(first_step_time):
        raise ValueError(f"first_step_time must be finite, got {first_step_time!r}")
    if not 0 <= max_steps <= MAX_STEPS:
        raise ValueError(f"max_steps must be 0..{MAX_STEPS}, got {max_steps!r}")
    dcm = np.asarray(dcm, dtype=float)
    rotation = _rotation(heading)
    stances = [(stance_side, np.asarray(stance_ankle, dtype=float))]
    swings = [None if swing_foot is None else np.asarray(swing_foot, dtype=float)]
    if other_ankle is not None:
        stances.append((_other(stance_side), np.asarray(other_ankle, dtype=float)))
        swings = [stances[1][1], stances[0][1]]
    for name, value in (("dcm", dcm), *((f"{side} ankle", a) for side, a in stances),
                        *(("swing_foot", a) for a in swings[:1] if a is not None)):
        if value.shape != (2,) or not np.all(np.isfinite(value)):
            raise ValueError(f"{name} must be a finite (x, y), got {value!r}")
    if other_ankle is None:
        depth = float(_box_depth(rotation.T @ (dcm - stances[0][1]), _cop_box(limits, stance_side)[None])[0])
    else:
        depth = _hull_depth(dcm, np.concatenate([_cop_corners(limits, s, a, rotation) for s, a in stances]))
    if depth >= 0.0 or max_steps == 0:
        return Capturability(0 if depth >= 0.0 else -1, depth, depth * omega)
    for steps in range(1, max_steps + 1):
        best = _deepest(dcm, steps, stances, swings, limits, omega, first_step_time, rotation)
        margin, (sequence, index, local, ankle) = best
        if margin >= 0.0:
            return Capturability(steps, margin, margin * omega,
                                 _witness(local, sequence, index, limits, omega, ankle, rotation))
    return Capturability(-1, margin, margin * omega)


def swing_touchdown_time(params, lift: float, lift_rate: float = 0.0, lift_accel: float = 0.0) -> float:
    """The swing's least time [s] to touch down from height ``lift`` [m], vertical rate [m/s] and acceleration
    [m/s^2]: its descent within the stop's limits (:func:`~drake_estop.planning.problems.descent_time`), no
    sooner than the planner's shortest landing (``params.min_landing_time``)."""
    from drake_estop.planning.problems import descent_time

    return max(descent_time(lift, params, lift_rate, lift_accel), params.min_landing_time)


def state_capturability(state, *, omega: float, limits: SteppingLimits, params) -> Capturability:
    """:func:`capturability` of a walk's or a measured :class:`~drake_estop.planning.gait.PatternState`.

    Parameters
    ----------
    state : PatternState
        Its COG [m] and velocity [m/s] give the DCM (eq. 4); in single support it stands on the support foot,
        the swing's least touchdown time from its height and rates (:func:`swing_touchdown_time`), else on
        both feet (the rear one, or the left standing, first).
    omega : float
        The LIPM's natural frequency [1/s].
    limits : SteppingLimits
        Where and when the feet can land.
    params : StopParameters
        The stop's limits (the swing's descent).

    Returns
    -------
    Capturability
        The verdict.
    """
    dcm = np.asarray(state.com, dtype=float) + np.asarray(state.com_vel, dtype=float) / omega
    if state.support == "single":
        stance, swing = state.support_foot, _other(state.support_foot)
        first = swing_touchdown_time(params, *(float(getattr(state, key)[swing][2])
                                               for key in ("feet", "feet_vel", "feet_acc")))
        other, swing_foot = None, np.asarray(state.feet[swing][:2], dtype=float)
    else:
        stance = state.rear_foot or "left"
        first, other = limits.min_step_time, np.asarray(state.feet[_other(stance)][:2], dtype=float)
        swing_foot = None
    return capturability(dcm, omega=omega, stance_ankle=np.asarray(state.feet[stance][:2], dtype=float),
                         stance_side=stance, limits=limits, first_step_time=first,
                         heading=float(state.feet_yaw[stance]), other_ankle=other,
                         swing_foot=swing_foot)


def largest_push_speed(state, direction, *, omega: float, limits: SteppingLimits, params,
                       resolution: float = 0.01, top: float = 2.0) -> float:
    """The largest impulsive push speed [m/s] along ``direction`` (world xy, normalised here) that leaves
    ``state`` capturable (:func:`state_capturability`): the COG velocity changed by it, searched upwards in
    steps of ``resolution`` [m/s] up to ``top``; 0 where the state itself is not capturable."""
    direction = np.asarray(direction, dtype=float)
    norm = float(np.linalg.norm(direction))
    if not (np.all(np.isfinite(direction)) and norm > 0.0):
        raise ValueError(f"direction must be a finite non-zero (x, y), got {direction!r}")
    unit, best = direction / norm, 0.0
    for speed in np.arange(0.0, top + resolution / 2, resolution):
        pushed = _replace_velocity(state, np.asarray(state.com_vel, dtype=float) + speed * unit)
        if not state_capturability(pushed, omega=omega, limits=limits, params=params).capturable:
            break
        best = float(speed)
    return best


def _replace_velocity(state, com_vel):
    from dataclasses import replace

    return replace(state, com_vel=com_vel)
