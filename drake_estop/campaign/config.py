"""Campaign configuration: the sampled ranges (YAML), their validation, and per-run sampling.

The ranges live in ``default.yaml`` (package data, the documented defaults);
``--config FILE.yaml`` overrides them key by key. :func:`sample_run` turns a
run's seed into a :class:`RunParameters`, whose :meth:`RunParameters.argv`
is the ``drake-estop simulate --physics`` command that runs (and reproduces) it.

A run's seed derives from the campaign seed and the run index
(:func:`run_seed`); its parameters derive from that seed alone.
"""

from __future__ import annotations

import functools
import math
import shlex
from dataclasses import asdict, dataclass, fields, replace
from importlib import resources

import numpy as np
import yaml

#: The servo tick the stop signal is snapped to [s] (``StopParameters.servo_period``).
SERVO_PERIOD = 0.005
#: The physics plant step that push times and durations are snapped to [s].
PLANT_STEP = 0.001
#: Sole inner half-width [m]: feet closer than twice this overlap (``GaitParameters``).
_SOLE_INNER = 0.055


class ConfigError(ValueError):
    """A bad campaign input; the message names the field or option (the CLI exits with status 2)."""


@dataclass(frozen=True)
class Bound:
    """What a config value may be: ``low``/``high`` (None: unbounded), open ends, a unit, integer-valued."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    unit: str = ""
    integer: bool = False

    def check(self, key: str, value) -> float:
        """``value`` as a number, or :class:`ConfigError` naming ``key``."""
        kind = "an integer" if self.integer else "a number"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"config {key}: needs {kind}, got {value!r}")
        if self.integer and int(value) != value:
            raise ConfigError(f"config {key}: needs {kind}, got {value!r}")
        low_bad = self.low is not None and (value < self.low or (self.low_open and value == self.low))
        high_bad = self.high is not None and (value > self.high or (self.high_open and value == self.high))
        if low_bad or high_bad:
            left = "-inf" if self.low is None else f"{'(' if self.low_open else '['}{self.low:g}"
            right = "inf" if self.high is None else f"{self.high:g}{')' if self.high_open else ']'}"
            raise ConfigError(f"config {key}: {value!r} is outside {left}, {right}{self.unit}")
        return int(value) if self.integer else float(value)


#: Every config key (``section.name``): (field of :class:`CampaignConfig`, allowed values, is a range).
KEYS = {
    "signal.phase": ("signal_phase", Bound(0.0, 1.0), True),
    "gait.step_length": ("step_length", Bound(0.0, 0.4, unit=" m"), True),
    "gait.step_time": ("step_time", Bound(0.3, 2.0, unit=" s"), True),
    "gait.step_width": ("step_width", Bound(2 * _SOLE_INNER, 0.4, low_open=True, unit=" m"), True),
    "push.impulse": ("push_impulse", Bound(0.0, unit=" N s"), True),
    "push.direction": ("push_direction", Bound(unit=" deg"), True),
    "push.onset": ("push_onset", Bound(-1.0, 1.0, unit=" s"), True),
    "push.duration": ("push_duration", Bound(PLANT_STEP, 1.0, unit=" s"), True),
    "model.mass_scale": ("mass_scale", Bound(0.0, low_open=True), True),
    "model.torso_mass_scale": ("torso_mass_scale", Bound(0.0, low_open=True), True),
    "model.torso_com_offset": ("torso_com_offset", Bound(-0.1, 0.1, unit=" m"), True),
    "environment.friction": ("friction", Bound(0.0, 1.6, low_open=True, high_open=True), True),
    "sensors.latency": ("latency", Bound(0, 20, unit=" ticks", integer=True), True),
    "sensors.noise_probability": ("noise_probability", Bound(0.0, 1.0), False),
    "run.timeout": ("timeout", Bound(0.0, low_open=True, unit=" s"), False),
}


@dataclass(frozen=True)
class CampaignConfig:
    """The sampled ranges, each ``(low, high)`` in the units of ``default.yaml``, and the run settings.

    Build it with :func:`default_config` or :func:`load_config` (which validate);
    :attr:`KEYS` maps the YAML keys onto these fields.
    """

    signal_phase: tuple
    step_length: tuple  # [m]
    step_time: tuple  # [s]
    step_width: tuple  # [m]
    push_impulse: tuple  # [N s]
    push_direction: tuple  # [deg]
    push_onset: tuple  # [s] from the signal
    push_duration: tuple  # [s]
    mass_scale: tuple
    torso_mass_scale: tuple
    torso_com_offset: tuple  # [m]
    friction: tuple
    latency: tuple  # [ticks]
    noise_probability: float
    timeout: float  # [s] wall time per run

    def as_yaml_dict(self) -> dict:
        """The config as the nested mapping of the YAML file (lists for ranges)."""
        nested = {}
        for key, (name, _, is_range) in KEYS.items():
            section, leaf = key.split(".")
            value = getattr(self, name)
            nested.setdefault(section, {})[leaf] = list(value) if is_range else value
        return nested


def _flatten(mapping, prefix="") -> dict:
    if not isinstance(mapping, dict):
        raise ConfigError(f"config {prefix.rstrip('.') or 'file'}: needs a mapping of keys, got {mapping!r}")
    flat = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def _range(key: str, value, bound: Bound) -> tuple:
    if not (isinstance(value, (list, tuple)) and len(value) == 2):
        raise ConfigError(f"config {key}: needs a range [low, high], got {value!r}")
    low, high = (bound.check(key, v) for v in value)
    if low > high:
        raise ConfigError(f"config {key}: low {low:g} > high {high:g}")
    return (low, high)


def config_from_mapping(mapping: dict, base: CampaignConfig | None = None) -> CampaignConfig:
    """Validate a nested mapping (the YAML) onto ``base`` (every key needed if None).

    Raises :class:`ConfigError` naming the key: an unknown key, a missing one
    (without ``base``), a value outside its bound (e.g. a negative impulse),
    or a range with low > high.
    """
    flat = _flatten(mapping)
    unknown = sorted(set(flat) - set(KEYS))
    if unknown:
        raise ConfigError(f"config: unknown key {unknown[0]!r} (known keys: {', '.join(KEYS)})")
    values = {} if base is None else {name: getattr(base, name) for name, _, _ in KEYS.values()}
    for key, (name, bound, is_range) in KEYS.items():
        if key in flat:
            values[name] = _range(key, flat[key], bound) if is_range else bound.check(key, flat[key])
        elif name not in values:
            raise ConfigError(f"config: missing key {key!r}")
    return CampaignConfig(**values)


def _read_yaml(text: str, source: str) -> dict:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ConfigError(f"config {source}: not valid YAML ({error})") from None
    return {} if data is None else data


def default_config() -> CampaignConfig:
    """The shipped ``default.yaml`` (every key present)."""
    text = resources.files("drake_estop.campaign").joinpath("default.yaml").read_text()
    return config_from_mapping(_read_yaml(text, "default.yaml"))


def load_config(path=None) -> CampaignConfig:
    """The default config, overridden key by key by the YAML file at ``path`` (if given)."""
    if path is None:
        return default_config()
    try:
        with open(path) as handle:
            text = handle.read()
    except OSError as error:
        raise ConfigError(f"--config: cannot read {path}: {error.strerror}") from None
    return config_from_mapping(_read_yaml(text, str(path)), default_config())


# --------------------------------------------------------------------------
# Sampling.


def run_seed(campaign_seed: int, run_index: int) -> int:
    """The seed of run ``run_index`` of the campaign ``campaign_seed``: an integer in [0, 2**63).

    63 bits keep it in a signed 64-bit column and make two runs of a campaign
    sharing a seed improbable (about 5e-12 for 10,000 runs).
    """
    sequence = np.random.SeedSequence([int(campaign_seed), int(run_index)])
    return int(sequence.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def _snap(value: float, step: float) -> float:
    """``value`` on the grid of ``step``, with a short decimal representation."""
    return round(round(value / step) * step, 6)


def _number(value: float) -> str:
    """``value`` in the shortest exact decimal form without an exponent (``-0.00005``, ``3.4``, ``57.0``)."""
    return np.format_float_positional(float(value), unique=True, trim="0")


@dataclass(frozen=True)
class RunParameters:
    """One run: every value of its ``drake-estop simulate --physics`` command (SI units, degrees).

    ``run`` is the run's index in its campaign (a label); everything else
    follows from ``seed`` and the config (:func:`sample_run`).
    """

    run: int
    seed: int
    signal_phase: float  # share of the stride at the signal (after snapping it to the tick)
    estop_time: float  # [s] stop signal
    step_length: float  # [m]
    step_time: float  # [s]
    step_width: float  # [m]
    push_time: float  # [s] start of the push
    push_fx: float  # [N]
    push_fy: float  # [N]
    push_duration: float  # [s]
    mass_scale: float
    torso_mass_scale: float
    torso_com_offset: float  # [m]
    friction: float
    latency: int  # [ticks]
    sensor_noise: bool
    robot: str = "default"  # the campaign's robot (a built-in name or a description file)

    @property
    def push_impulse(self) -> float:
        """[N s] magnitude of the push's impulse (after rounding the forces)."""
        return math.hypot(self.push_fx, self.push_fy) * self.push_duration

    @property
    def push_direction(self) -> float:
        """[deg] in [0, 360): 0 forward (+x), 90 left (+y)."""
        return math.degrees(math.atan2(self.push_fy, self.push_fx)) % 360.0

    @property
    def push_onset(self) -> float:
        """[s] from the stop signal to the start of the push."""
        return round(self.push_time - self.estop_time, 6)

    def argv(self) -> list:
        """The ``simulate`` arguments (after ``drake-estop``) that run exactly these parameters.

        Numbers are written in positional notation, shortest exact form
        (argparse takes ``-5e-05`` for an option, ``-0.00005`` for a number).
        """
        f = _number
        robot = [] if self.robot == "default" else ["--robot", self.robot]
        argv = ["simulate", "--physics", *robot, "--estop-time", f(self.estop_time),
                "--step-length", f(self.step_length), "--step-time", f(self.step_time),
                "--step-width", f(self.step_width),
                "--push", *(f(v) for v in (self.push_time, self.push_fx, self.push_fy, self.push_duration)),
                "--mass-scale", f(self.mass_scale), "--torso-mass-scale", f(self.torso_mass_scale),
                "--torso-com-offset", f(self.torso_com_offset), "--friction", f(self.friction),
                "--latency", str(self.latency), "--seed", str(self.seed)]
        return argv + (["--sensor-noise"] if self.sensor_noise else [])

    def command(self) -> str:
        """The shell command that reproduces the run."""
        return shlex.join(["drake-estop", *self.argv()])

    def record(self) -> dict:
        """The parameters as a flat dict, with the derived push impulse, direction and onset (the robot is the
        campaign's: its manifest and each run's command name it)."""
        values = {name: value for name, value in asdict(self).items() if name != "robot"}
        return {**values, "push_impulse": self.push_impulse, "push_direction": self.push_direction,
                "push_onset": self.push_onset}


def _uniform(rng, bounds) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _signal_time(gait_values: dict, phase: float, robot: str = "default") -> tuple:
    """(signal time on the servo tick [s], its actual share of the stride) for the sampled ``phase``, on the
    gait of ``robot`` with ``gait_values``."""
    from drake_estop.planning.gait import NominalPattern

    gait = replace(_robot_gait(robot), **gait_values)
    start, end = NominalPattern(gait).stride()
    t = _snap(start + phase * (end - start), SERVO_PERIOD)
    t = min(max(t, _snap(start, SERVO_PERIOD)), _snap(end, SERVO_PERIOD))
    return t, round(min(max((t - start) / (end - start), 0.0), 1.0), 6)


@functools.lru_cache(maxsize=8)
def _robot_gait(robot: str):
    """The own gait of ``robot`` (a built-in name or a description file), read once per campaign, not per run."""
    from drake_estop.robots import as_robot, gait_parameters

    return gait_parameters(as_robot(robot))


def sample_run(config: CampaignConfig, seed: int, run: int = 0, robot: str = "default") -> RunParameters:
    """Draw run ``run``'s parameters from ``numpy.random.default_rng(seed)``, in a fixed order.

    Every range gets one draw even when low == high, so that changing one
    range does not shift the others. Times are snapped (the signal to the
    5 ms servo tick, the push to the 1 ms plant step) and every value is
    rounded to a short decimal, so that the command line carries it exactly.
    ``robot``: the campaign's (its gait places the signal in the stride).
    """
    rng = np.random.default_rng(seed)
    phase = _uniform(rng, config.signal_phase)
    gait = {"step_length": round(_uniform(rng, config.step_length), 4),
            "step_time": _snap(_uniform(rng, config.step_time), SERVO_PERIOD),
            "step_width": round(_uniform(rng, config.step_width), 4)}
    impulse = _uniform(rng, config.push_impulse)
    direction = math.radians(_uniform(rng, config.push_direction))
    onset = _uniform(rng, config.push_onset)
    duration = max(_snap(_uniform(rng, config.push_duration), PLANT_STEP), PLANT_STEP)
    model = {name: _uniform(rng, getattr(config, name)) for name in ("mass_scale", "torso_mass_scale",
                                                                      "torso_com_offset", "friction")}
    latency = int(rng.integers(config.latency[0], config.latency[1] + 1))
    noise = bool(rng.random() < config.noise_probability)
    estop_time, phase = _signal_time(gait, phase, robot)
    force = impulse / duration
    return RunParameters(
        run=int(run), seed=int(seed), signal_phase=round(phase, 6), estop_time=estop_time, **gait,
        push_time=_snap(estop_time + onset, PLANT_STEP), push_fx=round(force * math.cos(direction), 2),
        push_fy=round(force * math.sin(direction), 2), push_duration=duration,
        mass_scale=round(model["mass_scale"], 4), torso_mass_scale=round(model["torso_mass_scale"], 4),
        torso_com_offset=round(model["torso_com_offset"], 5), friction=round(model["friction"], 4),
        latency=latency, sensor_noise=noise, robot=robot)


def campaign_runs(config: CampaignConfig, campaign_seed: int, runs: int, robot: str = "default") -> list:
    """:class:`RunParameters` of runs 0 .. ``runs`` - 1 of the campaign ``campaign_seed`` on ``robot``."""
    return [sample_run(config, run_seed(campaign_seed, i), i, robot) for i in range(runs)]


def scaled_to_robot(config: CampaignConfig, robot: str) -> CampaignConfig:
    """``config`` as the same campaign for ``robot`` (a built-in name or a description file): the step
    length, time and width ranges scaled by the robot's own gait against the default robot's, and the push
    impulses by its mass against the default robot's, so that the pushes give the same speeds [m/s]."""
    from drake_estop.robots import as_robot, gait_parameters
    from drake_estop.robots.measure import robot_facts

    ours, theirs = as_robot("default"), as_robot(robot)
    if theirs.name == ours.name:
        return config
    base, gait = gait_parameters(ours), gait_parameters(theirs)
    scale = {"step_length": gait.step_length / base.step_length, "step_time": gait.step_time / base.step_time,
             "step_width": gait.step_width / base.step_width,
             "push_impulse": robot_facts(theirs).mass / robot_facts(ours).mass}
    return replace(config, **{name: tuple(round(v * factor, 4) for v in getattr(config, name))
                              for name, factor in scale.items()})


PARAMETER_FIELDS = tuple(f.name for f in fields(RunParameters) if f.name != "robot") + (
    "push_impulse", "push_direction", "push_onset")
