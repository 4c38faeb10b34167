"""Hole-filling quality on real disocclusions (docs/inpaint_quality.md).

Middlebury Teddy and Cones: the left view warped into the right camera by ``_core.warp_with_holes``;
the disoccluded pixels of the right view are scored against the real right view
(benchmarks/bench_inpaint_quality.py defines every score). Only the relations the issue asks for
that were *measured to hold* are asserted; the one measured not to hold on Teddy (metameric's FLIP
at or below depth-aware push-pull's) is a strict xfail, so that a change that reaches it is seen.
The cause of that miss is pinned on Teddy with the bench's two diagnostic fills (metameric with
sigma = 0, and with the ground truth's own band sigma): FLIP rises with the noise, and more with
the true statistics than with the estimated ones.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("IBR_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))

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
# Teddy also gets the two diagnostic fills (metameric's sigma = 0 and the truth's sigma); Cones
# only what its tests use (the file stays ~15 s).
_DIAGNOSTICS = {"Teddy": ("metameric_mean", "metameric_oracle")}


def results(name: str) -> dict:
    if not (DATA / "middlebury" / name).is_dir():
        pytest.skip(f"real data absent: {DATA / 'middlebury' / name} (set IBR_SHARED_DATA)")
    if name not in _CACHE:
        B = _bench()
        case = B.middlebury_case(DATA, name)
        _CACHE[name] = B.evaluate(case, methods=("pushpull", "pushpull_depth", "metameric") + _DIAGNOSTICS.get(name, ()))
    return _CACHE[name]


@pytest.mark.parametrize("name", ["Teddy", "Cones"])
def test_metameric_beats_pushpull_on_statistics(name):
    # Measured (3 seeds): statistics distance D metameric 0.260 on Teddy against classic push-pull
    # 0.553 / depth-aware 0.363; Cones 0.310 against 0.646 / 0.653 (every seed below both on all 8
    # cases of docs/inpaint_quality.md). Margin 0.05 (half the smaller measured gap): band
    # statistics of a noise fill move by ~0.01-0.02 between seeds.
    r = results(name)
    best_pp = min(r["pushpull"]["stats"], r["pushpull_depth"]["stats"])
    for s in r["metameric"]["per_seed"]:
        assert s["stats"] < best_pp - 0.05, (s["stats"], best_pp)


@pytest.mark.parametrize("name", ["Teddy", "Cones"])
def test_metameric_keeps_the_pushpull_mean(name):
    # The fill's mean is the depth-aware push-pull (ibrtools.inpaint.metameric, step 4): the hole's mean
    # colour ("bleed") is no worse than depth-aware push-pull's (measured Teddy 0.048 vs 0.073,
    # Cones 0.052 vs 0.053; before the fix 0.217 / 0.112), and PSNR, which the noise lowers, stays
    # within 2.5 dB of it (measured 0.3 / 1.8 dB below; before the fix 5.5 / 4.7 dB). Margins: 0.01
    # on bleed and 2.5 dB cover the seed-to-seed spread (FLIP and PSNR move by ~0.02 / ~0.3 dB).
    r = results(name)
    mm, pd = r["metameric"], r["pushpull_depth"]
    assert mm["bleed"] < pd["bleed"] + 0.01, (mm["bleed"], pd["bleed"])
    assert mm["psnr"] > pd["psnr"] - 2.5, (mm["psnr"], pd["psnr"])


def test_teddy_metameric_flip_not_worse_than_classic_pushpull():
    # The "does not lose on FLIP" against the classic push-pull (the paper's baseline):
    # holds on Teddy by a wide margin (measured 0.399, seeds 0.397-0.403, against 0.489); also on
    # Books and Art (tie), not on Cones, Dolls and the lego views (docs/inpaint_quality.md).
    r = results("Teddy")
    for s in r["metameric"]["per_seed"]:
        assert s["flip"] < r["pushpull"]["flip"] - 0.05, (s["flip"], r["pushpull"]["flip"])


@pytest.mark.xfail(strict=True, reason="measured: metameric FLIP 0.399 (seeds 0.397-0.403) vs depth-aware push-pull "
                   "0.378 on Teddy. Cause (docs/inpaint_quality.md): the noise itself. Without it (sigma = 0) metameric "
                   "scores 0.349, with the ground truth's own band sigma 0.425: FLIP compares pixel by pixel, and an "
                   "independent texture with the right statistics differs from the true one more than a smooth fill does")
def test_teddy_metameric_flip_not_worse_than_depth_aware_pushpull():
    r = results("Teddy")
    assert r["metameric"]["flip"] <= r["pushpull_depth"]["flip"]


def test_teddy_noise_with_truer_statistics_costs_more_flip():
    # The cause of the xfail above. Measured on Teddy (3 seeds): FLIP 0.349 with sigma = 0 (metameric's
    # mean alone), 0.399 with the push-pulled sigma (metameric), 0.425 with the ground truth's own
    # local band sigma (an oracle estimate), while the statistics distance D falls 0.395 -> 0.260 ->
    # 0.218. Better statistics buy D and cost FLIP. Margins: 0.02 on FLIP steps of 0.05 and 0.026
    # (FLIP moves by <= 0.006 between seeds, so the 3-seed means move less); 0.1 on D steps of 0.135 /
    # 0.177 (sigma = 0 to either noisy fill).
    r = results("Teddy")
    zero, mm, oracle = r["metameric_mean"], r["metameric"], r["metameric_oracle"]
    assert zero["flip"] < mm["flip"] - 0.02, (zero["flip"], mm["flip"])
    assert mm["flip"] < oracle["flip"] - 0.01, (mm["flip"], oracle["flip"])
    assert oracle["stats"] < zero["stats"] - 0.1 and mm["stats"] < zero["stats"] - 0.1, (oracle["stats"], mm["stats"], zero["stats"])


def test_teddy_metameric_mean_beats_linear_depth_aware_pushpull():
    # Metameric's mean is the depth-aware push-pull of the *display* (sRGB-encoded) values; on Teddy it
    # beats the linear depth-aware push-pull on FLIP (measured 0.349 vs 0.378), PSNR (16.96 vs 15.89 dB)
    # and bleed (0.046 vs 0.073), so at sigma = 0 metameric is not "the" depth-aware push-pull of the
    # table. Deterministic fills: margins (0.015, 0.5 dB) only absorb kernel changes that move a fill a little.
    r = results("Teddy")
    zero, pd = r["metameric_mean"], r["pushpull_depth"]
    assert zero["flip"] < pd["flip"] - 0.015, (zero["flip"], pd["flip"])
    assert zero["psnr"] > pd["psnr"] + 0.5, (zero["psnr"], pd["psnr"])


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
