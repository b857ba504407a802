"""Draw the online controller's Drake diagram, from its own Graphviz, as the README's architecture picture.

    python diagrams/draw_architecture.py docs/architecture     # writes docs/architecture.dot (+ .svg)

The diagram is the one ``drake-estop simulate --physics`` runs (:func:`drake_estop.physics.online.
build_online_diagram`). Its ``GetGraphvizString`` lists every port of every system (the plant has
dozens) and a logger per logged signal; for a readable picture the loggers are left out, and so are
the rows of ports that nothing is connected to. The SVG is rendered with Graphviz's ``dot`` where it
is installed, else with the WebAssembly Graphviz of ``@hpcc-js/wasm-graphviz-cli`` (on the
path, or through ``npx``, which downloads it once); with neither,
only the ``.dot`` file is written (render it anywhere).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

_EDGE = re.compile(r"^(s\d+):(y\d+):e -> (s\d+):(u\d+):w$", re.M)
_NODE = re.compile(r"^(s\d+) \[shape=none, border=0, label=<\n.*?\n>\];\n", re.M | re.S)
_ROW = re.compile(r"<TR>\n<TD PORT=\"(u\d+)\"[^\n]*\n<TD PORT=\"(y\d+)\"[^\n]*\n</TR>\n"
                  r"|<TR>\n<TD PORT=\"([uy]\d+)\"[^\n]*\n</TR>\n")


def online_graphviz() -> str:
    """The Graphviz text of the online controller's diagram (the paper's 3.4 s stop)."""
    from drake_estop import NominalPattern, StopParameters, build_online_diagram, controller_stop_parameters

    handles = build_online_diagram(NominalPattern(), controller_stop_parameters(StopParameters()), 3.4)
    return handles.diagram.GetGraphvizString(max_depth=1)


def connected_only(dot: str) -> str:
    """``dot`` without its loggers and without the rows of ports nothing else is connected to."""
    loggers = {m.group(1) for m in _NODE.finditer(dot) if "VectorLogSink" in m.group(0)}
    used = set()
    for source, output, target, input_ in _EDGE.findall(dot):
        if target not in loggers:
            used |= {(source, output), (target, input_)}

    def node(match):
        name = match.group(1)
        if name in loggers:
            return ""
        span = None  # a spanning cell whose own row went, for the next row kept

        def row(r):
            nonlocal span
            cells = re.findall(r"<TD PORT=\"([uy]\d+)\"[^\n]*\n", r.group(0))
            spanning = [c for c in re.findall(r"<TD PORT=[^\n]*\n", r.group(0)) if "ROWSPAN" in c]
            if not any((name, port) in used for port in cells):
                span = span or (spanning[0] if spanning else None)
                return ""
            text = r.group(0)
            if span and len(cells) == 1:  # the spanning cell opens the row it now starts
                side_u = 'PORT="u' in span
                first, rest = text.split("\n", 1)
                text = first + "\n" + (span + rest if side_u else rest.replace("</TR>", span + "</TR>", 1))
                span = None
            return text
        return _respan(_ROW.sub(row, match.group(0)))

    dot = _NODE.sub(node, dot)
    return "\n".join(line for line in dot.split("\n")
                     if not any(re.search(rf"\b{logger}:", line) for logger in loggers))


def _respan(node: str) -> str:
    """``node`` with its spanning cell reaching down to its last port row."""
    rows = node.split("<TR>")
    for index, row in enumerate(rows):
        if "ROWSPAN" in row:
            rows[index] = re.sub(r'ROWSPAN="\d+"', f'ROWSPAN="{len(rows) - index}"', row)
    return "<TR>".join(rows)


def render_svg(dot_file: Path) -> Path | None:
    """``dot_file`` rendered to SVG beside it, with Graphviz or its WebAssembly build; None with neither."""
    svg = dot_file.with_suffix(".svg")
    if shutil.which("dot"):
        command = ["dot", "-Tsvg", str(dot_file), "-o", str(svg)]
        subprocess.run(command, check=True)
        return svg
    wasm = shutil.which("wasm-graphviz-cli")
    if wasm or shutil.which("npx"):
        command = [wasm] if wasm else ["npx", "--yes", "@hpcc-js/wasm-graphviz-cli"]
        done = subprocess.run([*command, "-T", "svg", str(dot_file)], capture_output=True, text=True)
        if done.returncode == 0 and done.stdout.lstrip().startswith(("<?xml", "<svg")):
            svg.write_text(done.stdout)
            return svg
    return None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="output path without suffix, e.g. docs/architecture")
    args = parser.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    dot_file = args.out.with_suffix(".dot")
    dot_file.write_text(connected_only(online_graphviz()))
    svg = render_svg(dot_file)
    print(f"wrote {dot_file}" + (f" and {svg}" if svg else " (no Graphviz found to render it)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
