"""Render a Meshcat HTML replay in headless Chromium and check the robot shows.

    python diagrams/render_replay.py FILE.html OUT.png [--chromium PATH]

Imports the installed ``drake_estop`` (``pip install -e .`` or ``pip install .``);
no path set-up.

Takes a screenshot of the replay at a time of its animation (``--budget-ms``),
then checks the robot is on screen: enough pixels
of the model's blue leg/arm material (``models/humanoid.urdf``: rgba 0.15 0.3
0.75, shaded) must be present (``--min-robot-pixels``); Meshcat's grey
gradient background and the thin trace lines do not reach that count (a
render of the same scene without the robot is the negative control in
``tests/test_replay_render.py``). Exit status 0 when the check passes, 1 when
the robot is not found, 2 when Chromium fails.
"""

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome")


def find_chromium(explicit=None):
    """Path of a Chromium binary, or None."""
    for candidate in ([explicit] if explicit else []) + list(CHROMIUM_CANDIDATES):
        if candidate and Path(candidate).is_file():
            return candidate
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _run_once(command, png, timeout):
    """One Chromium run in its own process group; the whole group dies on timeout.

    Headless Chromium sometimes writes the screenshot and then never exits, or
    hangs before writing it (seen on a fresh CI machine). Killing the group
    (renderer and GPU children included) keeps the pipes from holding us.
    """
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, start_new_session=True)
    try:
        _, stderr = process.communicate(timeout=timeout)
        return process.returncode, stderr
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        _, stderr = process.communicate()
        return None, stderr


def _address(html):
    """A file's URI, or ``html`` itself when it is already a URL (a live Meshcat's ``web_url()``)."""
    text = str(html)
    return text if text.startswith(("http://", "https://")) else Path(html).resolve().as_uri()


#: Appended to a replay's HTML: show the recording at a given time by seeking Meshcat's animator as
#: its commands arrive (a screenshot is taken once the page has loaded).
_SEEK_SCRIPT = """<script>
(function () {  // drake_estop render_replay: the replay at %(at).3f s
  function seek() {
    if (viewer.animator.duration > 0) {
      viewer.animator.seek(Math.min(%(at).6f, viewer.animator.duration));
      viewer.needs_render = true;
    }
  }
  const handle = viewer.handle_command_bytearray.bind(viewer);
  viewer.handle_command_bytearray = function (bytes) { handle(bytes); seek(); };
  seek();
})();
</script>
"""


def _seeking_copy(html: Path, at: float, folder: str) -> Path:
    """A copy of the replay ``html`` that opens at time ``at`` [s] of its animation."""
    text = html.read_text()
    end = text.rfind("</body>")
    if end < 0 or "MeshCat.Viewer" not in text:
        raise RuntimeError(f"{html} is not a Meshcat replay (no viewer or </body>)")
    copy = Path(folder) / "replay_at.html"
    copy.write_text(text[:end] + _SEEK_SCRIPT % {"at": at} + text[end:])
    return copy


def screenshot(html, png, *, chromium, size=(1280, 800), budget_ms=10000, timeout=60,
               attempts=3):
    """Run headless Chromium on ``html`` and write ``png``.

    A replay file is shown at ``budget_ms`` of its animation: a copy of it seeks
    Meshcat's animator there as the page loads, and Chromium takes the
    screenshot once the page has loaded. (Letting Chromium's virtual time play
    the animation instead, ``--virtual-time-budget``, hung about half of the
    runs with Chromium 156 and swiftshader; seeking has not hung.) A live
    Meshcat URL still plays for ``budget_ms`` of virtual time.

    Up to ``attempts`` runs of at most ``timeout`` seconds each; a screenshot
    written by a run that then hung is kept. Raises ``RuntimeError`` with
    Chromium's last stderr when no attempt writes the file.
    """
    png = Path(png).resolve()
    failures = []
    replay = None if str(html).startswith(("http://", "https://")) else Path(html)
    for _ in range(attempts):
        png.unlink(missing_ok=True)
        with tempfile.TemporaryDirectory(prefix="estop_chromium_") as profile:
            if replay is not None and replay.is_file():
                timing = [f"--timeout={max(int(budget_ms), 1000) + 10000}",
                          _address(_seeking_copy(replay, budget_ms / 1000.0, profile))]
            else:
                timing = [f"--virtual-time-budget={budget_ms}", _address(html)]
            command = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                       "--no-first-run", "--disable-background-networking",
                       "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                       "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
                       f"--user-data-dir={profile}", f"--screenshot={png}",
                       f"--window-size={size[0]},{size[1]}", *timing]
            returncode, stderr = _run_once(command, png, timeout)
        if png.is_file() and png.stat().st_size > 0:
            return png
        status = "timed out" if returncode is None else f"exit {returncode}"
        failures.append(f"{status}: {stderr[-1500:]}")
    raise RuntimeError(f"chromium wrote no screenshot in {attempts} attempts; last: {failures[-1]}")


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


def robot_pixels(png):
    """Pixels of the robot's blue material (shaded): blue well above red and green."""
    import matplotlib.image as mpimg

    image = np.round(mpimg.imread(str(png))[..., :3] * 255).astype(np.int32)
    red, green, blue = image[..., 0], image[..., 1], image[..., 2]
    return int(np.sum((blue > 110) & (blue > red + 50) & (blue > green + 30)))


def _image(png):
    import matplotlib.image as mpimg

    return np.round(mpimg.imread(str(png))[..., :3] * 255).astype(np.int32)


def robot_box(png):
    """Bounding box ``(top, bottom, left, right)`` of the robot's blue material, as fractions of the
    frame's height and width (None if absent).

    Thin lines of the same hue (the blue COG trace) are removed by a 5x5
    morphological opening first, so only the robot's limbs and chest count.
    The blue parts span the chest to the shins: a lower bound on the robot.
    """
    from scipy import ndimage

    image = _image(png)
    red, green, blue = image[..., 0], image[..., 1], image[..., 2]
    mask = ndimage.binary_opening((blue > 110) & (blue > red + 50) & (blue > green + 30),
                                  structure=np.ones((5, 5)))
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not rows.size:
        return None
    height, width = mask.shape
    return rows[0] / height, (rows[-1] + 1) / height, cols[0] / width, (cols[-1] + 1) / width


def robot_height_share(png):
    """Vertical extent of the robot's blue material as a share of the frame height (0 if absent);
    see :func:`robot_box` (head and soles are white and grey, so this is a lower bound)."""
    box = robot_box(png)
    return 0.0 if box is None else float(box[1] - box[0])


def colour_pixels(png, rgb, tolerance=40):
    """Pixels within ``tolerance`` (per channel, 0-255) of ``rgb`` (e.g. a trace's colour)."""
    image = _image(png)
    return int(np.sum(np.abs(image - np.asarray(rgb)).max(axis=-1) <= tolerance))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("html")
    parser.add_argument("png")
    parser.add_argument("--chromium", default=None)
    parser.add_argument("--budget-ms", type=int, default=10000,
                        help="replay time shown in the screenshot [ms] (default %(default)s)")
    parser.add_argument("--min-robot-pixels", type=int, default=800,
                        help="minimum count of robot-blue pixels (default %(default)s)")
    args = parser.parse_args(argv)
    chromium = find_chromium(args.chromium)
    if chromium is None:
        print("render_replay: no Chromium found (apt-get install chromium)", file=sys.stderr)
        return 2
    try:
        screenshot(args.html, args.png, chromium=chromium, budget_ms=args.budget_ms)
    except RuntimeError as error:
        print(f"render_replay: {error}", file=sys.stderr)
        return 2
    share, _ = foreground_stats(args.png)
    count = robot_pixels(args.png)
    ok = count >= args.min_robot_pixels
    print(f"{args.png}: {count} robot pixels, robot (blue parts) {robot_height_share(args.png) * 100:.0f}% of the "
          f"frame height, {share * 100:.1f}% non-background -> "
          f"{'robot on screen' if ok else 'robot not found'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
