"""Test helper: forward-warp one view into another camera with numpy (no pixel loops).

Used by the importer tests to check that cameras, depth and colour conventions agree: if an
importer got an axis, a scale or a pixel offset wrong, the warped source view would not line
up with the target's real image and the colour error would be large.

``warp`` unprojects every source pixel with known depth through the source camera, projects
the world point into the target camera, rounds to the nearest target pixel and keeps the
nearest point per pixel (a z-buffer by ``np.lexsort``). No hole filling: pixels nothing lands
on are invalid. ``compare`` measures the colour error on pixels valid in both.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def shared_data() -> Path | None:
    """../shared/data (or $IBR_SHARED_DATA), or None when absent."""
    env = os.environ.get("IBR_SHARED_DATA")
    p = Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"
    return p if p.is_dir() else None


def warp(color: np.ndarray, depth: np.ndarray, src_cam, dst_cam, src_mask: np.ndarray | None = None):
    """Forward-warp ``color`` (H, W, C) with ``depth`` (H, W; 0/inf = unknown) from ``src_cam``
    into ``dst_cam``. Returns (warped colour (h, w, C) float32, warped depth (h, w) in the
    target's depth convention (z for pinhole), valid (h, w) bool)."""
    depth = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(depth) & (depth > 0)
    if src_mask is not None:
        ok &= src_mask
    world = src_cam.unproject(np.where(ok, depth, 0.0))[ok]
    color = np.asarray(color)
    nch = color.shape[2] if color.ndim == 3 else 1
    cols = color[ok].reshape(-1, nch)
    xy, z = dst_cam.project(world)
    with np.errstate(invalid="ignore"):
        u = np.floor(xy[:, 0])
        v = np.floor(xy[:, 1])
        inside = np.isfinite(z) & (z > 0) & (u >= 0) & (u < dst_cam.width) & (v >= 0) & (v < dst_cam.height)
    u, v, z, cols = u[inside].astype(np.int64), v[inside].astype(np.int64), z[inside], cols[inside]
    lin = v * dst_cam.width + u
    order = np.lexsort((z, lin))  # by pixel, then nearest first
    lin_s = lin[order]
    first = np.ones(len(lin_s), bool)
    first[1:] = lin_s[1:] != lin_s[:-1]
    keep = order[first]
    h, w = dst_cam.height, dst_cam.width
    out = np.zeros((h * w, nch), np.float32)
    out_z = np.zeros(h * w, np.float64)
    valid = np.zeros(h * w, bool)
    out[lin[keep]] = cols[keep]
    out_z[lin[keep]] = z[keep]
    valid[lin[keep]] = True
    return out.reshape(h, w, -1), out_z.reshape(h, w), valid.reshape(h, w)


def compare(warped: np.ndarray, valid: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """Colour error of ``warped`` against ``target`` on ``valid`` (& ``mask``) pixels: mean
    absolute error (per channel, same units as the images), PSNR (peak 1) and the pixel count."""
    sel = valid if mask is None else valid & mask
    n = int(sel.sum())
    if n == 0:
        return {"mae": float("inf"), "psnr": 0.0, "count": 0}
    d = warped[sel].astype(np.float64) - target[sel].astype(np.float64)
    mse = float(np.mean(d * d))
    return {"mae": float(np.mean(np.abs(d))), "psnr": float(10 * np.log10(1.0 / max(mse, 1e-20))), "count": n}


def depth_agreement(warped_z: np.ndarray, valid: np.ndarray, target_z: np.ndarray) -> dict:
    """Relative depth error |z_warp - z_target| / z_target where both are known: median and the
    fraction of pixels within 2 %."""
    sel = valid & np.isfinite(target_z) & (target_z > 0)
    if not sel.any():
        return {"median_rel": float("inf"), "within_2pct": 0.0, "count": 0}
    rel = np.abs(warped_z[sel] - target_z[sel]) / target_z[sel]
    return {"median_rel": float(np.median(rel)), "within_2pct": float(np.mean(rel < 0.02)), "count": int(sel.sum())}
