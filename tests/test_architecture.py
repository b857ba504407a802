"""The README's architecture picture: the online diagram's own Graphviz, without loggers and unused ports."""

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("draw_architecture", ROOT / "diagrams" / "draw_architecture.py")
draw = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(draw)

EDGE = re.compile(r"^(s\d+):([yu]\d+):e -> (s\d+):([yu]\d+):w$", re.M)


@pytest.fixture(scope="module")
def graphviz():
    return draw.online_graphviz()


def _ports(dot, node):
    block = re.search(rf"^{node} \[shape=none.*?\n>\];$", dot, re.M | re.S).group(0)
    return set(re.findall(r'PORT="([uy]\d+)"', block))


def test_the_drawing_keeps_every_connection_and_each_connected_port(graphviz):
    drawn = draw.connected_only(graphviz)
    edges = EDGE.findall(drawn)
    kept_edges = [e for e in EDGE.findall(graphviz) if "VectorLogSink" not in _node_label(graphviz, e[2])]
    assert edges == kept_edges and len(edges) > 20
    for source, output, target, input_ in edges:
        assert output in _ports(drawn, source) and input_ in _ports(drawn, target)
    assert "VectorLogSink" in graphviz and "VectorLogSink" not in drawn
    for system in ("StopPlannerSystem", "StateEstimator", "WholeBodyIK", "EStopTrigger", "MultibodyPlant"):
        assert system in drawn


def test_unconnected_ports_are_left_out(graphviz):
    drawn = draw.connected_only(graphviz)
    connected = {(node, port) for source, output, target, input_ in EDGE.findall(drawn)
                 for node, port in ((source, output), (target, input_))}
    nodes = re.findall(r"^(s\d+) \[shape=none", drawn, re.M)
    for node in nodes:  # every row left has a connected port
        block = re.search(rf"^{node} \[shape=none.*?\n>\];$", drawn, re.M | re.S).group(0)
        for row in re.findall(r"<TR>\n(<TD PORT=.*?)</TR>", block, re.S):
            assert any((node, port) in connected for port in re.findall(r'PORT="([uy]\d+)"', row)), (node, row)
    plant = re.search(r"^(s\d+) \[shape=none[^\n]*\n<TABLE[^\n]*\n<TR><TD[^\n]*\n<B>MultibodyPlant", graphviz,
                      re.M).group(1)
    assert len(_ports(drawn, plant)) < len(_ports(graphviz, plant)) / 2


def test_the_committed_picture_is_this_diagram(graphviz):
    committed = (ROOT / "docs" / "architecture.dot").read_text()
    names = set(re.findall(r"name=(\w+)", committed))
    assert names == set(re.findall(r"name=(\w+)", draw.connected_only(graphviz)))
    assert (ROOT / "docs" / "architecture.svg").read_text().lstrip().startswith("<?xml")


def _node_label(dot, node):
    match = re.search(rf"^{node} \[shape=none.*?\n>\];$", dot, re.M | re.S)
    return match.group(0) if match else ""
