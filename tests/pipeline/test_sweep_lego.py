"""benchmarks/bench_hybrid_lego.py --hybrid-params: the hybrid render parameters of a setting chosen
by a sweep on the lego validation views (docs/hybrid.md "Parameters chosen by a sweep on lego
validation views"). Only the argument checks run here (no data is read): a bad key or value must
fail before the minutes-long preprocessing starts."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from ibrtools.errors import BadValueError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        return importlib.import_module("bench_hybrid_lego")
    finally:
        sys.path.remove(str(REPO / "benchmarks"))


def test_good_params_pass_the_check_and_reach_the_data_lookup(bench, tmp_path, monkeypatch, capsys):
    # An empty data directory: the checks pass, then the bench skips (returns 0) naming the data.
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    assert bench.main(["--validation", "--hybrid-params", '{"tau_var": 0.1, "geo_threshold": 0.02}']) == 0
    assert "nerf_lego" in capsys.readouterr().err


def test_unknown_hybrid_param_fails_before_the_data_is_read(bench, tmp_path, monkeypatch):
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    with pytest.raises(BadValueError, match="tau_vra"):
        bench.main(["--hybrid-params", '{"tau_vra": 0.1}'])


def test_bad_hybrid_param_value_fails(bench, tmp_path, monkeypatch):
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    with pytest.raises(BadValueError, match="sigma_blur"):
        bench.main(["--hybrid-params", '{"sigma_blur": -1}'])


def test_hybrid_params_must_be_a_json_object(bench, tmp_path, monkeypatch):
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    with pytest.raises(SystemExit) as e:
        bench.main(["--hybrid-params", "[0.1]"])
    assert e.value.code == 2


@pytest.mark.parametrize("flag", ["--hybrid-params", "--options"])
def test_malformed_json_is_a_usage_error_naming_the_flag(bench, tmp_path, monkeypatch, capsys, flag):
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    with pytest.raises(SystemExit) as e:
        bench.main([flag, "{tau_var: 0.1"])
    assert e.value.code == 2
    assert f"{flag}: not valid JSON" in capsys.readouterr().err


def test_folds_partition_the_forty_views(bench):
    """--fold: 10 folds of 4 views cover r_0, r_5 ... r_195 once each; fold 0 is the held-out set,
    fold 2 the validation set, and --fold offers exactly the others."""
    folds = [bench.fold_views(k) for k in range(10)]
    names = [n for f in folds for n in f]
    assert sorted(names, key=lambda n: int(n[2:])) == [f"r_{i}" for i in range(0, 200, 5)]
    assert folds[0] == bench.LEGO_HELDOUT and folds[2] == bench.LEGO_VALIDATION
    assert set(bench.FOLDS) == set(range(10)) - {0, 2}


@pytest.mark.parametrize("argv", [["--fold", "0"], ["--fold", "2"], ["--fold", "10"], ["--fold", "3", "--validation"],
                                  ["--fold", "3", "--write-docs"]])
def test_bad_fold_is_a_usage_error(bench, tmp_path, monkeypatch, capsys, argv):
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    with pytest.raises(SystemExit) as e:
        bench.main(argv)
    assert e.value.code == 2
    assert "--fold" in capsys.readouterr().err


def test_negative_speed_repeats_is_a_usage_error(bench, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("IBR_SHARED_DATA", str(tmp_path))
    with pytest.raises(SystemExit) as e:
        bench.main(["--speed-repeats", "-1"])
    assert e.value.code == 2
    assert "--speed-repeats must be >= 0" in capsys.readouterr().err
