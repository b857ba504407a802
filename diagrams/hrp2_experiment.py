"""Paper VI: the HRP-2 experiment (Fig. 13) on the simulated humanoid.

Step 0.15 m, cycle 0.8 s, the same weights as the simulations, the stop
signal at half of a single support phase (the third step's, so the walk is
in its steady cycle).  Writes the Meshcat replay and the COG/ZMP figure:

    python diagrams/hrp2_experiment.py [OUT_DIR] [--step N]

Uses the public API of the installed ``drake_estop`` (``pip install -e .`` or
``pip install .``), through ``scenario.py`` next to this script; no path set-up.
"""

import argparse
import sys
import warnings
from pathlib import Path

from scenario import describe, plot_cog_zmp, run_stop  # diagrams/scenario.py

from drake_estop import NominalPattern, load_scenario

# the paper's values, as data: scenarios/hrp2_experiment.yaml (its estop_time is the third step's mid single support)
SCENARIO = load_scenario(filename=Path(__file__).with_name("scenarios") / "hrp2_experiment.yaml")
GAIT, STOP = SCENARIO.gait, SCENARIO.stop


def mid_single_support(gait, step_index):
    """Time at half of the single support phase of step ``step_index`` (0-based)."""
    step = NominalPattern(gait).steps[step_index]
    return step["liftoff"] + 0.5 * gait.single_support_time


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="out", help="output directory (default out/)")
    parser.add_argument("--step", type=int, default=2, help="0-based step whose single support "
                        "is interrupted (default %(default)s)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("always", RuntimeWarning)
    signal = mid_single_support(GAIT, args.step)
    result = run_stop(GAIT, STOP, signal, html=out / "hrp2_experiment.html")
    print(describe(result))
    png = plot_cog_zmp(result, out / "hrp2_experiment_cog_zmp.png",
                       f"HRP-2 experiment setting: 0.15 m steps, signal {signal:.2f} s (mid single support)")
    print(f"wrote {out / 'hrp2_experiment.html'}, {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
