"""Hole-filling quality on real disocclusions (issue 5 "Targets"; docs/inpaint_quality.md).

Middlebury Teddy and Cones: the left view warped into the right camera by ``_core.warp_with_holes``;
the disoccluded pixels of the right view are scored against the real right view
(benchmarks/bench_inpaint_quality.py defines every score). Only the relations the issue asks for
that were *measured to hold* are asserted. The one measured not to hold (metameric "does not lose
on FLIP": it loses on every case) is recorded in docs/inpaint_quality.md, not asserted.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("IBR_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))

pytest.importorskip("cv2", reason="OpenCV (TELEA) is needed by the quality bench")
pytest.importorskip("flip_evaluator", reason="flip-evaluator is needed for the FLIP score")
pytest.importorskip("scipy", reason="scipy labels the hole components")


def _bench():
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import bench_inpaint_quality
    finally:
        sys.path.pop(0)
    return bench_inpaint_quality


_CACHE: dict[str, dict] = {}


def results(name: str) -> dict:
    if not (DATA / "middlebury" / name).is_dir():
        pytest.skip(f"real data absent: {DATA / 'middlebury' / name} (set IBR_SHARED_DATA)")
    if name not in _CACHE:
        B = _bench()
        case = B.middlebury_case(DATA, name)
        _CACHE[name] = B.evaluate(case, methods=("pushpull", "pushpull_depth", "metameric"))
    return _CACHE[name]


def test_teddy_metameric_beats_pushpull_on_statistics():
    # Measured (3 seeds): statistics distance D metameric 0.268 (every seed < 0.28) against
    # classic push-pull 0.553 and depth-aware 0.363. Margin 0.05 (half the measured gap to the
    # nearer push-pull): band statistics of a noise fill move by ~0.01 between seeds.
    # NOT asserted elsewhere: on Art, Books, lego r_50/r_100 metameric is *worse* than (one of)
    # the push-pulls on D (docs/inpaint_quality.md), so this is Teddy's relation, not a general one.
    r = results("Teddy")
    best_pp = min(r["pushpull"]["stats"], r["pushpull_depth"]["stats"])
    for s in r["metameric"]["per_seed"]:
        assert s["stats"] < best_pp - 0.05, (s["stats"], best_pp)


@pytest.mark.parametrize("name, margin", [("Teddy", 0.01), ("Cones", 0.003)])
def test_depth_aware_pushpull_bleeds_less_than_classic(name, margin):
    # "bleed" = size-weighted |mean fill - mean truth| per disoccluded component (sRGB): a fill that
    # pulls the foreground beside a disocclusion into it moves the hole's mean off the background.
    # Measured: Teddy 0.0732 depth-aware vs 0.0970 classic, Cones 0.0526 vs 0.0606 (also Art
    # 0.044 vs 0.062). Margins: ~40 % of the measured gaps (the fills are deterministic; the margin
    # is for kernel changes that move the fill a little, not for noise).
    # NOT general: on Books and the lego held-out views depth-aware is worse than classic on this
    # score (docs/inpaint_quality.md, findings), so only these cases are asserted.
    r = results(name)
    assert r["pushpull_depth"]["bleed"] < r["pushpull"]["bleed"] - margin


def test_bench_skips_cleanly_without_data(tmp_path, capsys):
    B = _bench()
    assert B.main(["--data", str(tmp_path / "absent")]) == 0
    assert "nothing measured" in capsys.readouterr().out
