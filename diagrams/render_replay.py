"""Render a Meshcat HTML replay in headless Chromium and check the robot shows.

    /work/venv/bin/python diagrams/render_replay.py FILE.html OUT.png [--chromium PATH]

Takes a screenshot after letting the page's virtual time run (the replay's
animation starts playing), then checks the image is not blank: the share of
pixels that differ from the dominant (background) colour must exceed
``--min-foreground`` and the image must have some variance.  Exit status 0
when the check passes, 1 when the image looks blank, 2 when Chromium fails.
"""

import argparse
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

import numpy as np

CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome")


def find_chromium(explicit=None):
    """Path of a Chromium binary, or None."""
    for candidate in ([explicit] if explicit else []) + list(CHROMIUM_CANDIDATES):
        if candidate and Path(candidate).is_file():
            return candidate
    return shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot(html, png, *, chromium, size=(1280, 800), budget_ms=10000, timeout=120):
    """Run headless Chromium on ``html`` and write ``png``."""
    with tempfile.TemporaryDirectory(prefix="estop_chromium_") as profile:
        command = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                   "--no-first-run", "--disable-background-networking",
                   "--disable-component-update", "--disable-sync", "--use-gl=swiftshader",
                   "--enable-unsafe-swiftshader", f"--user-data-dir={profile}",
                   f"--screenshot={Path(png).resolve()}", f"--window-size={size[0]},{size[1]}",
                   f"--virtual-time-budget={budget_ms}", Path(html).resolve().as_uri()]
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    if not Path(png).is_file():
        raise RuntimeError(f"chromium wrote no screenshot (exit {done.returncode}): "
                           f"{done.stderr[-2000:]}")
    return png


def foreground_stats(png):
    """(share of non-background pixels, pixel standard deviation) of ``png``."""
    import matplotlib.image as mpimg

    image = mpimg.imread(str(png))[..., :3]
    pixels = np.round(image.reshape(-1, 3) * 255).astype(np.int32)
    codes = pixels[:, 0] * 65536 + pixels[:, 1] * 256 + pixels[:, 2]
    values, counts = np.unique(codes, return_counts=True)
    background = values[np.argmax(counts)]
    bg_rgb = np.array([background // 65536, (background // 256) % 256, background % 256])
    differs = np.abs(pixels - bg_rgb).max(axis=1) > 24
    return float(differs.mean()), float(image.std())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("html")
    parser.add_argument("png")
    parser.add_argument("--chromium", default=None)
    parser.add_argument("--min-foreground", type=float, default=0.01,
                        help="minimum share of non-background pixels (default %(default)s)")
    args = parser.parse_args(argv)
    chromium = find_chromium(args.chromium)
    if chromium is None:
        print("render_replay: no Chromium found (apt-get install chromium)", file=sys.stderr)
        return 2
    try:
        screenshot(args.html, args.png, chromium=chromium)
    except (RuntimeError, subprocess.TimeoutExpired) as error:
        print(f"render_replay: {error}", file=sys.stderr)
        return 2
    share, std = foreground_stats(args.png)
    ok = share >= args.min_foreground and std > 0.01
    print(f"{args.png}: {share * 100:.1f}% non-background pixels, std {std:.3f} -> "
          f"{'robot on screen' if ok else 'looks blank'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
