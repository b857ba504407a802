"""Paper V.B: emergency stop in the double support phase (Fig. 11-12).

Step 0.3 m, cycle 0.8 s, signal at 3.5 s (double support), a_ds = 50,
b_ds = 1000.  Writes the Meshcat replay and the COG/ZMP figure (Fig. 12);
with ``--round`` the phase times are only rounded to servo ticks, as in the
paper, which shows its ZMP overshoot near 4 s:

    python diagrams/double_support_stop.py [OUT_DIR] [--round]

Uses the public API of the installed ``drake_estop`` (``pip install -e .`` or
``pip install .``), through ``scenario.py`` next to this script; no path set-up.
"""

import argparse
import sys
import warnings
from dataclasses import replace
from pathlib import Path

from scenario import describe, plot_cog_zmp, run_stop  # diagrams/scenario.py

from drake_estop import load_scenario

# the paper's values, as data: scenarios/double_support_stop.yaml (also `drake-estop simulate --scenario-file`)
SCENARIO = load_scenario(filename=Path(__file__).with_name("scenarios") / "double_support_stop.yaml")
GAIT, SIGNAL = SCENARIO.gait, SCENARIO.estop_time


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="out", help="output directory (default out/)")
    parser.add_argument("--round", action="store_true",
                        help="round the phase times only (the paper's quantisation)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("always", RuntimeWarning)
    stop = replace(SCENARIO.stop, quantisation="round" if args.round else "resolve")
    suffix = "_round" if args.round else ""
    html = out / f"double_support_stop{suffix}.html"
    result = run_stop(GAIT, stop, SIGNAL, html=html)
    print(describe(result))
    png = plot_cog_zmp(result, out / f"double_support_cog_zmp{suffix}.png",
                       "Stop in double support (signal 3.5 s): COG and ZMP (cf. Fig. 12)")
    print(f"wrote {html}, {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
