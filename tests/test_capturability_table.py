"""benchmarks/capturability_table.py: the largest capturable push speeds of a robot, as a markdown table."""

from scripts import load_script

from drake_estop.planning.gait import NominalPattern


def test_table_rows_and_what_crossovers_add(tmp_path, capsys):
    table = load_script("benchmarks/capturability_table.py")
    out = tmp_path / "CAPTURABILITY.md"
    assert table.main(["--robots", "default", "--out", str(out)]) == 0
    text = out.read_text()
    assert text == capsys.readouterr().out.rstrip("\n") + "\n"
    rows = [line.split("|")[1:-1] for line in text.splitlines() if line.startswith("| default")]
    assert len(rows) == 9  # three moments, three crossover variants
    speeds = {(r[1].strip(), r[2].strip()): [float(v) for v in r[4:]] for r in rows}
    reach = {r[2].strip(): float(r[3]) for r in rows}
    assert reach == {"legs": 0.0, "soles": 0.1, "none": 0.0}  # the default humanoid's legs allow no crossover
    for moment in table.moments(NominalPattern()):
        assert speeds[(moment, "legs")] == speeds[(moment, "none")]
        assert all(a >= b for a, b in zip(speeds[(moment, "soles")], speeds[(moment, "none")]))  # never less
    inward = table.DIRECTIONS.index("inward")
    assert speeds[("early single support", "soles")][inward] > speeds[("early single support", "none")][inward] + 0.1
