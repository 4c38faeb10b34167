"""Parameter sweeps: run time against error of a render method over a grid of its parameters, on
held-out views or the scene's targets (``ibr-bench``, Prakash et al. 2021 sec. 7 "Parameter
evaluation": 22 novel views of a synthetic scene).

Grammar of a sweep (``--sweep``, repeatable; docs/sweep.md):
``key=v1:v2:v3`` gives one parameter its values; several ``key=values`` groups are separated by
commas in one ``--sweep`` (``sigma=1:3:5,alpha=7``) or given as separate ``--sweep`` flags. The
configurations are the Cartesian product of every key's values, in the order given. Values are
read as int, float, true/false, or kept as strings; each method checks its own parameters.

For each configuration: the method is prepared once on the job's scene (held-out views removed),
every frame is rendered, timed (wall clock of ``render``) and scored against its ground truth
(``ibrtools.metrics.compare``: PSNR, SSIM, FLIP). Outputs in ``out_dir``: ``sweep.csv`` (one row
per configuration), ``sweep.md`` (Markdown table, best FLIP first), ``sweep.png`` (median time
against mean FLIP, Pareto front marked; matplotlib).
"""
from __future__ import annotations

import csv
import itertools
import math
import os
import time
from pathlib import Path

import numpy as np

from ibrtools.errors import BadValueError
from ibrtools.scene import Scene
from ibrtools.pipeline import job as J
from ibrtools.pipeline import plan as planning
from ibrtools.pipeline.report_html import FramePanel, data_uri, esc, page, panel_html, table, write_page
from ibrtools import methods
from ibrtools.inpaint.complete import DEFAULT_INPAINT, check_inpaint, complete, completion
from ibrtools.imageio import atomic_path


def _value(text: str):
    t = text.strip()
    if not t:
        raise BadValueError.about("grid", "empty value")
    low = t.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(t)
    except ValueError:
        pass
    try:
        f = float(t)
    except ValueError:
        return t
    if not math.isfinite(f):
        raise BadValueError.about("grid", f"value {t!r} is not finite")
    return f


def parse_sweep(specs: list[str] | None) -> dict[str, list]:
    """``["sigma=1:3:5,alpha=7", "gamma=5:7"]`` -> {"sigma": [1, 3, 5], "alpha": [7], "gamma": [5, 7]}."""
    grid: dict[str, list] = {}
    for spec in specs or []:
        for group in spec.split(","):
            group = group.strip()
            if not group:
                continue
            if "=" not in group or not group.split("=", 1)[0].strip():
                raise BadValueError.about("grid", f"expected key=v1:v2:... groups separated by commas, "
                                                  f"got {group!r}", spec)
            key, vals = group.split("=", 1)
            key = key.strip()
            if key in grid:
                raise BadValueError.about("grid", f"parameter {key!r} is given twice")
            grid[key] = [_value(v) for v in vals.split(":")]
    return grid


def configurations(grid: dict[str, list], base: dict | None = None) -> list[dict]:
    """The Cartesian product of the grid's values over ``base``."""
    keys = list(grid)
    return [{**(base or {}), **dict(zip(keys, combo))} for combo in itertools.product(*(grid[k] for k in keys))]


def sweep(scene: Scene, method: str, grid: dict[str, list], *, holdout: list[str] | None = None,
          base: dict | None = None, out_dir: str | os.PathLike | None = None, progress=None,
          frame_hook=None, inpaint: str = DEFAULT_INPAINT) -> list[dict]:
    """Run every configuration; return one row per configuration (params, times, mean metrics)
    and, with ``out_dir``, write sweep.csv / sweep.md / sweep.png there. Frames are scored as
    ``ibr-render`` writes them (complete: inpaint/complete.py, with ``inpaint``); a frame's time
    includes its completion. Before the first timed frame the first configuration renders the
    first frame once, untimed (the engine's first-use costs: thread pool, tables, buffers).

    ``progress(ci, n_configs, fi, n_frames)`` is called before each frame and once more with
    ``(n_configs, n_configs, 0, n_frames)`` at the end; ``frame_hook(ci, fi, frame, outputs,
    stage_ms, metrics)`` after each frame (the HTML report keeps thumbnails through it)."""
    name = methods.resolve(method, scene)
    job = planning.plan(scene, holdout=holdout) if holdout else planning.plan(scene)
    frames = [f for f in job.frames if f.truth is not None and f.truth.has_color]
    if not frames:
        raise BadValueError.about("holdout", "no frame with ground truth to score (hold out input views by name, "
                                             "or bench a scene whose targets have colour)")
    configs = configurations(grid, base)
    # Check every configuration's parameters before rendering anything.
    for c in configs:
        methods.create(name, c)
    check_inpaint(inpaint)
    rows = []
    for ci, cfg in enumerate(configs):
        m = methods.create(name, cfg)
        t0 = time.perf_counter()
        m.prepare(job.scene)
        prep_ms = (time.perf_counter() - t0) * 1e3
        background, mode = completion(m, job.scene, inpaint)
        if ci == 0:
            complete(m.render(frames[0].camera)[0], frames[0].camera, background, mode)  # warm-up
        times, metrics = [], []
        for fi, frame in enumerate(frames):
            if progress:
                progress(ci, len(configs), fi, len(frames))
            t1 = time.perf_counter()
            out, stage_ms = m.render(frame.camera)
            done = complete(out, frame.camera, background, mode)
            times.append((time.perf_counter() - t1) * 1e3)
            metrics.append(J._frame_metrics(done.color, done.hole, done.filled, frame.truth))
            if frame_hook:
                frame_hook(ci, fi, frame, {**out, "color": done.color, "hole": done.hole},
                           {"total": times[-1], **stage_ms, **done.stage_ms}, metrics[-1])
        row = {"config": ci, **{k: cfg.get(k) for k in grid}, "frames": len(frames),
               "prepare_ms": round(prep_ms, 2), "median_ms": round(float(np.median(times)), 3),
               "mean_ms": round(float(np.mean(times)), 3)}
        for key in ("psnr", "ssim", "flip"):
            vals = [x[key] for x in metrics if isinstance(x.get(key), (int, float)) and np.isfinite(x[key])]
            row[f"mean_{key}"] = round(float(np.mean(vals)), 5) if vals else None
        rows.append(row)
    if progress:
        progress(len(configs), len(configs), 0, len(frames))
    if out_dir is not None:
        write_outputs(rows, list(grid), Path(out_dir), title=f"{name} on {len(frames)} views")
    return rows


def pareto(rows: list[dict], x: str = "median_ms", y: str = "mean_flip") -> list[int]:
    """Indices of rows not dominated in (time, error): no other row is both faster and better."""
    pts = [(r[x], r[y], i) for i, r in enumerate(rows) if r.get(y) is not None]
    front = []
    for tx, ty, i in pts:
        if not any((ox <= tx and oy <= ty) and (ox < tx or oy < ty) for ox, oy, _ in pts):
            front.append(i)
    return sorted(front)


def write_outputs(rows: list[dict], keys: list[str], out_dir: Path, title: str = "") -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    cols = list(rows[0]) if rows else []
    with atomic_path(out_dir / "sweep.csv") as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols)
            w.writeheader()
            w.writerows(rows)
    front = set(pareto(rows))
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["mean_flip"] is None, rows[i]["mean_flip"] or 0))
    head = ["config", *keys, "median ms", "PSNR dB", "SSIM", "FLIP", "Pareto"]
    lines = [f"Sweep: {title}. Error = mean FLIP over the frames (lower is better); time = median "
             "wall-clock render time per frame.", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]

    def fmt(v, nd=4):
        return "—" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))

    for i in order:
        r = rows[i]
        lines.append("| " + " | ".join([str(r["config"]), *[fmt(r[k], 3) for k in keys], fmt(r["median_ms"], 1),
                                        fmt(r["mean_psnr"], 2), fmt(r["mean_ssim"]), fmt(r["mean_flip"]),
                                        "yes" if i in front else ""]) + " |")
    with atomic_path(out_dir / "sweep.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    pts = [(r["median_ms"], r["mean_flip"], i) for i, r in enumerate(rows) if r["mean_flip"] is not None]
    if pts:
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], c="tab:blue", s=18, label="configuration")
        fr = sorted((rows[i]["median_ms"], rows[i]["mean_flip"]) for i in front)
        if fr:
            ax.plot([p[0] for p in fr], [p[1] for p in fr], "-o", c="tab:red", ms=4, label="Pareto front")
        for x, y, i in pts:
            ax.annotate(str(rows[i]["config"]), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("median time per frame (ms)")
    ax.set_ylabel("mean FLIP (lower is better)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(out_dir / "sweep.png") as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def bench_report(rows: list[dict], keys: list[str], out_dir: str | os.PathLike, path: str | os.PathLike, *,
                 title: str, panels: list[FramePanel] | None = None, panels_config=None,
                 plot: str | os.PathLike | None = None) -> Path:
    """The page of an ``ibr-bench`` sweep: the run-time-against-error plot (``plot``, PNG file,
    embedded), the table of configurations (best FLIP first, Pareto front marked) and the frames
    of one configuration (``panels``, of configuration ``panels_config``)."""
    out_dir = Path(out_dir)
    body = []
    plot = Path(plot) if plot is not None else out_dir / "sweep.png"
    if plot.is_file():
        body.append("<h2>Run time against error</h2>"
                    f'<figure><img src="{data_uri(plot.read_bytes())}" alt="run time against error"></figure>')
    front = set(pareto(rows))
    order = sorted(range(len(rows)), key=lambda i: (rows[i].get("mean_flip") is None, rows[i].get("mean_flip") or 0))
    head = ["config", *keys, "frames", "prepare ms", "median ms", "PSNR dB", "SSIM", "FLIP", "Pareto"]
    trs = [[rows[i]["config"], *[rows[i].get(k) for k in keys], rows[i].get("frames"), rows[i].get("prepare_ms"),
            rows[i].get("median_ms"), rows[i].get("mean_psnr"), rows[i].get("mean_ssim"), rows[i].get("mean_flip"),
            "yes" if i in front else ""] for i in order]
    body.append("<h2>Configurations</h2><p>Error = mean FLIP over the frames (lower is better; PSNR and SSIM "
                "higher is better); time = median wall-clock render time per frame. Best first.</p>")
    body.append(table(head, trs))
    if panels:
        body.append(f"<h2>Frames of configuration {esc(panels_config)}</h2>")
        body.extend(panel_html(p) for p in panels)
    return write_page(path, page(title, "".join(body)))
