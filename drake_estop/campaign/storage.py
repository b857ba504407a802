"""Results of a campaign on disk: one parquet part per finished run, written atomically.

Layout of ``--out DIR``::

    DIR/.lock                held (flock) by the campaign process writing here
    DIR/campaign.json        the campaign's seed and config (a resume must match them) and its sessions
    DIR/results/run-*.parquet  one row per finished run, written as soon as it finishes
    DIR/results.parquet      the parts merged (at the end of each session)

Every file is written to a temporary name in its folder, flushed to disk
(``fsync``) and renamed over its final name (``os.replace``, atomic on POSIX):
a kill at any moment, SIGKILL included, leaves either the complete file or
none, plus at most a ``.tmp-*`` file that readers ignore and the next session
removes. Reading merges ``results.parquet`` and the parts and keeps one row
per seed (a kill between a merge and the removal of the merged parts leaves
the same row twice; the copies are identical).
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from drake_estop.campaign.config import ConfigError

#: The criteria of a physics run (``drake_estop.physics.criteria.CRITERIA``).
CRITERIA = ("no_fall", "no_slip", "comes_to_rest", "rests_at_midpoint", "cop_in_support",
            "joint_speed_within_limits")

_PARAMETERS = [
    ("run", pa.int64()), ("seed", pa.int64()), ("signal_phase", pa.float64()), ("estop_time", pa.float64()),
    ("step_length", pa.float64()), ("step_time", pa.float64()), ("step_width", pa.float64()),
    ("push_time", pa.float64()), ("push_fx", pa.float64()), ("push_fy", pa.float64()),
    ("push_duration", pa.float64()), ("mass_scale", pa.float64()), ("torso_mass_scale", pa.float64()),
    ("torso_com_offset", pa.float64()), ("friction", pa.float64()), ("latency", pa.int64()),
    ("sensor_noise", pa.bool_()), ("push_impulse", pa.float64()), ("push_direction", pa.float64()),
    ("push_onset", pa.float64()),
]
#: The key numbers of a run (from its ``simulate --summary``), SI units.
NUMBERS = ("time_to_rest", "rest_after_halt", "final_cog_offset", "cog_travel", "pelvis_z_min", "torso_tilt_max",
           "slip_max", "cop_margin_min", "sole_off_plan_max", "sole_turn_max")
_OUTCOME = [
    ("outcome", pa.string()), ("error", pa.string()), ("success", pa.bool_()), ("case", pa.string()),
    ("support", pa.string()), *((name, pa.bool_()) for name in CRITERIA), *((n, pa.float64()) for n in NUMBERS),
    ("replans", pa.int64()), ("replan_failures", pa.int64()), ("steps", pa.int64()), ("capture_landings", pa.int64()),
    ("recovery_steps", pa.int64()), ("joint_velocity_violations", pa.int64()),
    # the measured state's N-step capturability at the later of the signal and the push's end
    # (drake_estop.planning.capturability): the least steps (-1: none of N <= 3) and the margin [m]
    ("capture_steps", pa.int64()), ("capture_margin", pa.float64()),
    # where the CoP left the planned support (null where it did not): the stop's phase and the sole's edge
    ("cop_exit_phase", pa.string()), ("cop_exit_edge", pa.string()),
    ("tick_p99", pa.float64()), ("realtime_factor", pa.float64()), ("wall_time", pa.float64()),
    ("command", pa.string()),
]
#: One row per run: the sampled parameters, the outcome, each criterion, the key numbers, the wall time.
SCHEMA = pa.schema(_PARAMETERS + _OUTCOME)
#: Columns that depend on the machine's load, not on the run (left out when comparing two tables).
TIMING_COLUMNS = ("tick_p99", "realtime_factor", "wall_time")


def row_table(row: dict) -> pa.Table:
    """A one-row table of :data:`SCHEMA`; ValueError if ``row`` lacks a column or has an unknown one."""
    missing, unknown = set(SCHEMA.names) - set(row), set(row) - set(SCHEMA.names)
    if missing or unknown:
        raise ValueError(f"result row: missing columns {sorted(missing)}, unknown columns {sorted(unknown)}")
    return pa.Table.from_pylist([row], schema=SCHEMA)


def _fsync_folder(folder: Path):
    descriptor = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def atomic_write(path: Path, write):
    """Call ``write(handle)`` on a temporary file next to ``path``, fsync it and rename it to ``path``."""
    path = Path(path)
    temporary = path.with_name(f".tmp-{path.name}-{os.getpid()}")
    with open(temporary, "wb") as handle:
        write(handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
    _fsync_folder(path.parent)


class ResultStore:
    """The result files of the campaign in ``folder`` (see the module docstring)."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.parts = self.folder / "results"
        self.table_path = self.folder / "results.parquet"
        self.manifest_path = self.folder / "campaign.json"

    # -- before anything is written

    def check(self, manifest: dict):
        """ConfigError (naming ``--out``) if the folder cannot hold this campaign; writes nothing.

        ``--out`` must not be a file; a folder that already holds a campaign
        must hold this one (same seed and config), so that a resume adds to it.
        """
        if self.folder.exists() and not self.folder.is_dir():
            raise ConfigError(f"--out: {self.folder} is a file, not a folder")
        if not self.manifest_path.exists():
            return
        stored = json.loads(self.manifest_path.read_text())
        for key, default in (("seed", None), ("config", None), ("robot", "default")):
            if stored.get(key, default) != manifest.get(key, default):
                raise ConfigError(f"--out: {self.folder} holds a campaign with another {key} "
                                  f"({stored.get(key, default)!r}); resume with the same --seed, --config and "
                                  "--robot or use a new folder")

    # -- writing

    def open(self, manifest: dict, session: dict):
        """Create the folders, lock them for this process, record the campaign and this session, and remove
        stale temporary files. ConfigError if another campaign process holds the lock (``DIR/.lock``, an
        ``flock`` the kernel releases when the holder exits, SIGKILL included)."""
        self.parts.mkdir(parents=True, exist_ok=True)
        self._lock = open(self.folder / ".lock", "w")  # held until this process exits
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            raise ConfigError(f"--out: another campaign process is writing to {self.folder}") from None
        stored = json.loads(self.manifest_path.read_text()) if self.manifest_path.exists() else dict(manifest)
        stored.setdefault("sessions", []).append(session)
        self._write_json(self.manifest_path, stored)
        for folder in (self.folder, self.parts):
            for stale in folder.glob(".tmp-*"):
                stale.unlink()

    @staticmethod
    def _write_json(path, data):
        atomic_write(path, lambda handle: handle.write(json.dumps(data, indent=2, sort_keys=True).encode()))

    def write(self, row: dict):
        """Write one finished run as its own part file (atomic)."""
        table = row_table(row)
        name = f"run-{int(row['run']):06d}-{int(row['seed'])}.parquet"
        atomic_write(self.parts / name, lambda handle: pq.write_table(table, handle))

    def compact(self):
        """Merge the parts into ``results.parquet`` (atomic), then remove the merged parts."""
        parts = sorted(self.parts.glob("run-*.parquet")) if self.parts.exists() else []
        if not parts:
            return
        table = self.read()
        atomic_write(self.table_path, lambda handle: pq.write_table(table, handle))
        for part in parts:
            part.unlink()

    # -- reading

    def read(self) -> pa.Table:
        """Every finished run, one row per seed, sorted by run index."""
        files = [self.table_path] if self.table_path.exists() else []
        if self.parts.exists():
            files += sorted(self.parts.glob("run-*.parquet"))
        if not files:
            return SCHEMA.empty_table()
        table = pa.concat_tables([pq.read_table(path, schema=SCHEMA) for path in files])
        seeds = table.column("seed").to_pylist()
        first = {}
        for index, seed in enumerate(seeds):
            first.setdefault(seed, index)
        table = table.take(sorted(first.values()))
        return table.sort_by([("run", "ascending"), ("seed", "ascending")])

    def seeds(self) -> set:
        """Seeds of the finished runs."""
        return set(self.read().column("seed").to_pylist())
