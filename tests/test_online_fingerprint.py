"""benchmarks/online_fingerprint.py compare: equal to the bit or not (its dump runs physics: minutes)."""

import numpy as np
import pytest
from scripts import load_script


@pytest.fixture(scope="module")
def fingerprint():
    return load_script("benchmarks/online_fingerprint.py")


def _dump(path, **series):
    np.savez(path, **series)
    return str(path)


def test_compare_passes_equal_dumps_and_names_the_first_difference(fingerprint, tmp_path, capsys):
    series = {"paper_3.4/com_meas_x": np.array([0.1, 0.2, np.nan]), "paper_3.4/ik_q": np.eye(3)}
    a = _dump(tmp_path / "a.npz", **series)
    assert fingerprint.compare(a, _dump(tmp_path / "b.npz", **series)) == 0  # NaN equals NaN
    assert "equal to the bit" in capsys.readouterr().out
    one_ulp = np.eye(3)
    one_ulp[2, 2] = np.nextafter(1.0, 2.0)  # the smallest difference there is
    nudged = dict(series, **{"paper_3.4/ik_q": one_ulp})
    assert fingerprint.compare(a, _dump(tmp_path / "c.npz", **nudged)) == 1
    out = capsys.readouterr().out
    assert "paper_3.4/ik_q: 1 of 9 values differ, the first at flat index 8" in out
    assert fingerprint.compare(a, _dump(tmp_path / "d.npz", **{"paper_3.4/ik_q": np.eye(3)})) == 1
    assert "only in" in capsys.readouterr().out
    reshaped = dict(series, **{"paper_3.4/com_meas_x": np.array([0.1, 0.2])})
    assert fingerprint.compare(a, _dump(tmp_path / "e.npz", **reshaped)) == 1
    assert "shape (3,) against (2,)" in capsys.readouterr().out


def test_dump_refuses_workers_below_one_naming_the_option(fingerprint, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        fingerprint.main(["dump", str(tmp_path / "x.npz"), "--workers", "0"])
    assert exit_info.value.code == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
