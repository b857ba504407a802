"""benchmarks/capturability_table.py: the largest capturable push speeds of a robot, as a markdown table."""

from scripts import load_script

from drake_estop.planning.gait import NominalPattern


def test_table_rows_and_the_crossovers_gain(tmp_path, capsys):
    table = load_script("benchmarks/capturability_table.py")
    out = tmp_path / "CAPTURABILITY.md"
    assert table.main(["--robots", "default", "--out", str(out)]) == 0
    text = out.read_text()
    assert text == capsys.readouterr().out.rstrip("\n") + "\n"
    rows = [line.split("|")[1:-1] for line in text.splitlines() if line.startswith("| default")]
    assert len(rows) == 6  # three moments, with and without crossovers
    speeds = {(r[1].strip(), r[2].strip()): [float(v) for v in r[3:]] for r in rows}
    for moment in table.moments(NominalPattern()):
        with_crossover, without = speeds[(moment, "yes")], speeds[(moment, "no")]
        assert all(a >= b for a, b in zip(with_crossover, without))  # a region more never catches less
    inward = table.DIRECTIONS.index("inward")
    assert speeds[("early single support", "yes")][inward] > speeds[("early single support", "no")][inward] + 0.1
