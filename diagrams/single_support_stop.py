"""Paper V.A: emergency stop in the single support phase (Fig. 8-10).

Step 0.3 m, cycle 0.8 s, signal at 3.4 s (late single support), a_ss = 5,
b_ss = 1000, with the IV.A crouch.  Writes the Meshcat replay, the COG/ZMP
figure (Fig. 9) and the knee comparison with and without crouch (Fig. 10):

    python diagrams/single_support_stop.py [OUT_DIR]

Uses the public API of the installed ``drake_estop`` (``pip install -e .`` or
``pip install .``), through ``scenario.py`` next to this script; no path set-up.
"""

import argparse
import sys
import warnings
from dataclasses import replace
from pathlib import Path

from scenario import describe, plot_cog_zmp, plot_knees, run_stop  # diagrams/scenario.py

from drake_estop import load_scenario

# the paper's values, as data: scenarios/single_support_stop.yaml (also `drake-estop simulate --scenario-file`)
SCENARIO = load_scenario(filename=Path(__file__).with_name("scenarios") / "single_support_stop.yaml")
GAIT, STOP, SIGNAL = SCENARIO.gait, SCENARIO.stop, SCENARIO.estop_time


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="out", help="output directory (default out/)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("always", RuntimeWarning)
    crouch = run_stop(GAIT, STOP, SIGNAL, html=out / "single_support_stop.html")
    print("with crouch:   ", describe(crouch))
    flat = run_stop(GAIT, replace(STOP, crouch=False), SIGNAL)
    print("without crouch:", describe(flat))
    plot_cog_zmp(crouch, out / "single_support_cog_zmp.png",
                 "Stop in single support (signal 3.4 s): COG and ZMP (cf. Fig. 9)")
    plot_knees({"crouch": crouch, "constant COG height": flat}, out / "single_support_knees.png",
               "Knee joints with and without crouch (cf. Fig. 10)")
    print(f"wrote {out / 'single_support_stop.html'}, {out / 'single_support_cog_zmp.png'}, "
          f"{out / 'single_support_knees.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
