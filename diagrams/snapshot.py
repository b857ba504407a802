"""Picture of the robot mid-stop: run the diagram with a live Meshcat to a chosen
time and screenshot the Meshcat page in headless Chromium.

    python diagrams/snapshot.py [--estop-time 3.4] [--at 3.75] [--robot g1] [--out docs/robot_mid_stop.png]

Uses the public API of the installed ``drake_estop`` (``pip install -e .`` or
``pip install .``); no path set-up. The camera is the follow camera of the
replay and the live view.
"""

import argparse
import subprocess
import tempfile
from pathlib import Path

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from render_replay import find_chromium  # diagrams/render_replay.py (the script folder is on sys.path)

from drake_estop import AddEmergencyStop, make_meshcat


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--estop-time", type=float, default=3.4)
    parser.add_argument("--at", type=float, default=3.75, help="simulation time of the picture [s]")
    parser.add_argument("--robot", default="default", help="a built-in robot or a description file")
    parser.add_argument("--out", default="docs/robot_mid_stop.png")
    args = parser.parse_args()
    meshcat = make_meshcat()
    builder = DiagramBuilder()
    AddEmergencyStop(builder, robot=args.robot, estop_time=args.estop_time, meshcat=meshcat)  # the robot's gait
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(args.at)
    chromium = find_chromium()
    out = Path(args.out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                        "--disable-background-networking", "--disable-component-update", "--disable-sync",
                        "--use-gl=swiftshader", "--enable-unsafe-swiftshader", f"--user-data-dir={profile}",
                        f"--screenshot={out}", "--window-size=1200,800", "--virtual-time-budget=8000",
                        meshcat.web_url()], capture_output=True, timeout=120, check=False)
    print(f"{out} ({'written' if out.is_file() else 'NOT written'})")


if __name__ == "__main__":
    main()
