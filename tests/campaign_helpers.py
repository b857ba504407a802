"""Stand-in runners for the campaign tests: cheap, deterministic functions of the run's parameters.

They replace only the physics run (``runner`` of ``run_campaign``); the
sampling, the Dask executor, the storage and the report are the real ones.
The workers import this module by name (the test puts ``tests/`` on the path).
"""

import math
import os
import time

from drake_estop.campaign.storage import CRITERIA

#: Seconds each stand-in run takes (so that a campaign can be killed part-way).
SLEEP = float(os.environ.get("CAMPAIGN_FAKE_SLEEP", "0.2"))


def fake_run(params, timeout):
    """Success iff the push impulse is under 20 N s; run index 3 mod 7 raises, 5 mod 7 returns NaN."""
    time.sleep(SLEEP)
    if params.run % 7 == 3:
        raise RuntimeError(f"injected failure in run {params.run}")
    success = params.push_impulse < 20.0
    outcome = {"outcome": "success" if success else "failure", "success": success,
               "case": "one-step" if params.signal_phase < 0.7 else "next-step",
               "support": "single" if params.signal_phase < 0.8 else "double",
               **{name: success for name in CRITERIA},
               "cog_travel": 0.2 + params.push_impulse / 100, "final_cog_offset": 0.001 * params.mass_scale,
               "replans": int(params.push_impulse // 10), "tick_p99": 0.004}
    if params.run % 7 == 5:
        outcome["cog_travel"] = math.nan
    return outcome
