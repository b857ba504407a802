"""The long-lived ``simulate`` process of a campaign worker: ``python -m drake_estop.campaign.child``.

A Dask worker runs its runs here, not in its own process, so that a run
that hangs can be killed (:class:`drake_estop.campaign.runner.SimulateProcess`)
while the process stays warm between runs (Drake, the IK plant and the
compiled planner load once, about 3 s a run saved).

Protocol: one JSON line per job on stdin, ``{"argv": [...]}`` (the arguments
of ``drake-estop``, without ``--summary``); one JSON line per job on the
original stdout::

    {"returncode": int, "summary": dict | null, "stderr": str, "exception": str | null}

``returncode`` and ``summary`` are exactly what ``drake-estop <argv>
--summary FILE`` gives; ``stderr`` is what it printed there (the error
message of exit status 2); ``exception`` an uncaught exception (type,
message and the traceback's last lines). Anything else written to the
standard output (prints, Drake's C++ log) goes to the standard error, so
the protocol stream carries only replies.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import sys
import tempfile
import traceback


def run_job(argv: list) -> dict:
    """Run ``drake-estop <argv> --summary TMP`` in this process; the reply of the protocol."""
    from drake_estop.cli import main

    out, err = io.StringIO(), io.StringIO()
    with tempfile.TemporaryDirectory(prefix="drake-estop-run-") as folder:
        path = os.path.join(folder, "summary.json")
        exception = None
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = main([*argv, "--summary", path])
        except Exception as error:  # noqa: BLE001 - reported to the campaign as this run's error row
            code = None
            exception = "".join(traceback.format_exception_only(type(error), error)).strip()
            exception += "\n" + "".join(traceback.format_tb(error.__traceback__)[-3:])
        summary = None
        if os.path.exists(path):
            with open(path) as handle:
                summary = json.load(handle)
    return {"returncode": code, "summary": summary, "stderr": err.getvalue()[-2000:], "exception": exception}


def serve(requests, replies):
    """Answer each JSON job line of ``requests`` with a JSON reply line on ``replies``."""
    for line in requests:
        if not line.strip():
            continue
        reply = run_job(json.loads(line)["argv"])
        replies.write(json.dumps(reply) + "\n")
        replies.flush()


def main():
    # Ctrl-C in a terminal reaches the whole process group: the campaign process stops and reports; a run
    # here is never cut short by it (it would look like a crashed run). The child ends when its stdin closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # stray output (C++ included) must not reach the protocol
    serve(sys.stdin, replies)


if __name__ == "__main__":
    main()
