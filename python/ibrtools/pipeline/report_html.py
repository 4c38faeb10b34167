"""Self-contained HTML reports of render jobs and parameter sweeps (``ibr-render --report-html``,
``ibr-bench``; docs/reports.md).

One page, nothing outside it: images are embedded as base64 PNG (encoded by OpenImageIO), bars are plain HTML/CSS, the only script is a check that every image
decoded (it sets ``data-images-ok="k/n"`` on ``<body>`` and shows a warning when k < n).

Per frame: the rendered view beside the ground truth, an error heat map (the FLIP map when
``flip-evaluator`` is installed, else the per-pixel mean absolute sRGB error; with its colour bar),
the selection mask of hybrid methods or the hole mask when the frame has one, stage-time bars and
the frame's numbers. Large jobs: images are shrunk to at most ``max_width`` pixels wide (box
filter) and at most ``max_frames`` frames are shown, evenly spaced, with a note saying so.
Every name and value put in the page goes through :func:`html.escape`.
"""
from __future__ import annotations

import base64
import html
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ibrtools.errors import BadValueError, ShapeError
from ibrtools.imageio import srgb8
from ibrtools.imageio import atomic_path, linear_to_srgb, read_image
from ibrtools.metrics import flip, flip_available

MAX_FRAMES = 24
MAX_WIDTH = 640

# Matplotlib's "magma" colour map at 9 evenly spaced points (0 = black, 1 = pale yellow),
# interpolated linearly: dark = small error, bright = large.
_MAGMA = np.array([[0, 0, 4], [28, 16, 68], [79, 18, 123], [129, 37, 129], [181, 54, 122],
                   [229, 80, 100], [251, 135, 97], [254, 194, 135], [252, 253, 191]], np.float64)


# --- images -------------------------------------------------------------------------------------
def encode_png(image: np.ndarray) -> bytes:
    """8-bit PNG bytes of a uint8 image (H, W) grey or (H, W, 3) RGB, written by OpenImageIO (the
    project's image I/O) into a temporary file and read back."""
    import tempfile

    import OpenImageIO as oiio

    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise BadValueError(f"encode_png: expected uint8, got {a.dtype}")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ShapeError(f"encode_png: expected (H, W) or (H, W, 3), got {np.asarray(image).shape}")
    h, w, c = a.shape
    with tempfile.TemporaryDirectory(prefix="ibr-png-") as tmp:
        path = os.path.join(tmp, "image.png")
        out = oiio.ImageOutput.create(path)
        if out is None or not out.open(path, oiio.ImageSpec(w, h, c, oiio.UINT8)) \
                or not out.write_image(np.ascontiguousarray(a)) or not out.close():
            from ibrtools.errors import InternalError

            raise InternalError(f"encode_png: OpenImageIO could not write a PNG: {oiio.geterror()}")
        return Path(path).read_bytes()


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def shrink(image: np.ndarray, max_width: int = MAX_WIDTH) -> np.ndarray:
    """Box-filter ``image`` (H, W[, C], float) by the smallest integer factor that makes it at
    most ``max_width`` wide (edge rows/columns beyond a multiple of the factor are dropped)."""
    a = np.asarray(image, np.float32)
    f = -(-a.shape[1] // max(1, int(max_width)))
    if f <= 1:
        return a
    h, w = a.shape[0] // f * f, a.shape[1] // f * f
    if h == 0:  # very wide and short: keep one row of blocks
        h, a = f, np.repeat(a[:1], f, axis=0)
    a = a[:h, :w]
    return a.reshape(h // f, f, w // f, f, *a.shape[2:]).mean(axis=(1, 3))


def colormap(values: np.ndarray, vmax: float) -> np.ndarray:
    """Values in [0, vmax] -> magma RGB uint8 (clipped)."""
    t = np.clip(np.nan_to_num(np.asarray(values, np.float64) / max(vmax, 1e-12)), 0.0, 1.0) * (len(_MAGMA) - 1)
    i = np.minimum(t.astype(np.int64), len(_MAGMA) - 2)
    f = (t - i)[..., None]
    return np.rint(_MAGMA[i] * (1 - f) + _MAGMA[i + 1] * f).astype(np.uint8)


def error_map(rendered: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, str, float]:
    """(map (H, W), kind, colour-scale maximum): FLIP's per-pixel error (scale 0..1) when
    flip-evaluator is installed, else the mean absolute sRGB error over the channels (scale 0
    to its 99th percentile, at least 1/255)."""
    r = np.nan_to_num(np.asarray(rendered, np.float32)[..., :3])
    t = np.nan_to_num(np.asarray(truth, np.float32)[..., :3])
    if r.shape != t.shape:
        raise ShapeError(f"error map: rendered {r.shape} and ground truth {t.shape} differ")
    if flip_available():
        _, fmap = flip(np.clip(r, 0, 1), np.clip(t, 0, 1), return_map=True)
        return np.asarray(fmap, np.float32), "FLIP", 1.0
    e = np.abs(linear_to_srgb(np.clip(r, 0, 1)) - linear_to_srgb(np.clip(t, 0, 1))).mean(axis=2)
    return e.astype(np.float32), "|error| (sRGB)", float(max(np.percentile(e, 99), 1.0 / 255.0))


# --- a frame's panel ------------------------------------------------------------------------------
@dataclass
class FramePanel:
    """What the page shows of one frame (images already shrunk, 8-bit)."""

    name: str
    rendered: np.ndarray | None = None          # uint8 RGB
    truth: np.ndarray | None = None             # uint8 RGB
    error: np.ndarray | None = None             # uint8 RGB (colour-mapped)
    error_kind: str = ""
    error_max: float = 0.0
    mask: np.ndarray | None = None              # uint8 RGB or grey: hybrid selection / holes
    mask_label: str = ""
    hole: np.ndarray | None = None              # uint8 grey: hybrid frames' holes
    stage_ms: dict = field(default_factory=dict)
    numbers: dict = field(default_factory=dict)  # metrics and facts (row/col), shown as a table
    note: str = ""                              # e.g. the failure of a frame


def frame_panel(name: str, rendered: np.ndarray | None, truth: np.ndarray | None = None, *,
                selection: np.ndarray | None = None, hole: np.ndarray | None = None,
                stage_ms: dict | None = None, numbers: dict | None = None, note: str = "",
                max_width: int = MAX_WIDTH) -> FramePanel:
    """Build a frame's panel from full-size linear float images (``selection``: RGB float in
    [0, 1], hybrid methods; ``hole``: bool (H, W))."""
    p = FramePanel(str(name), stage_ms=dict(stage_ms or {}), numbers=dict(numbers or {}), note=note)
    if rendered is not None:
        p.rendered = srgb8(np.asarray(shrink(rendered, max_width), np.float32)[..., :3])
        if truth is not None and np.asarray(truth).shape[:2] == np.asarray(rendered).shape[:2]:
            # The map compares the images as shown (shrunk): FLIP costs ~0.6 s per 640x480 frame
            # on this machine, ~4 s at 1080p; report.json keeps the full-resolution scores.
            small_r, small_t = shrink(rendered, max_width), shrink(truth, max_width)
            p.truth = srgb8(np.asarray(small_t, np.float32)[..., :3])
            emap, p.error_kind, p.error_max = error_map(small_r, small_t)
            p.error = colormap(emap, p.error_max)
    if selection is not None:
        sel = np.asarray(selection, np.float32)
        p.mask = np.clip(np.rint(shrink(sel, max_width) * 255), 0, 255).astype(np.uint8)
        p.mask_label = "selection (red PVM, green TM, blue ULR)"
        if hole is not None and np.asarray(hole).any():
            p.hole = np.clip(np.rint(shrink(np.asarray(hole, np.float32), max_width) * 255), 0, 255).astype(np.uint8)
    elif hole is not None and np.asarray(hole).any():
        p.mask = np.clip(np.rint(shrink(np.asarray(hole, np.float32), max_width) * 255), 0, 255).astype(np.uint8)
        p.mask_label = "holes (white)"
    return p


def pick_frames(n: int, cap: int = MAX_FRAMES) -> list[int]:
    """Indices of the frames shown: all when n <= cap, else ``cap`` evenly spaced (first and last kept)."""
    if n <= cap:
        return list(range(n))
    return sorted(set(np.rint(np.linspace(0, n - 1, max(1, cap))).astype(int).tolist()))


# --- HTML ---------------------------------------------------------------------------------------
_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em;color:#222;background:#fafafa}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}
th{background:#eee}td:first-child,th:first-child{text-align:left}
.frame{background:#fff;border:1px solid #ddd;border-radius:4px;padding:.6em;margin:1em 0}
.imgs{display:flex;flex-wrap:wrap;gap:10px}.imgs figure{margin:0}.imgs img{display:block;max-width:100%;image-rendering:pixelated}
figcaption{font-size:.8em;color:#555}.cbar{display:flex;align-items:center;gap:4px;font-size:.75em}
.cbar img{height:10px;width:120px}
.bars{font-size:.8em;margin:.4em 0}.bar{display:flex;align-items:center;gap:6px;margin:1px 0}
.bar span.k{width:11em;text-align:right;color:#444}.bar span.v{color:#444}
.bar div{height:10px;background:#4c72b0;min-width:1px}
.note{background:#fff3cd;border:1px solid #e0c36a;padding:.4em .6em;border-radius:3px}
.fail{background:#f8d7da;border:1px solid #d9828b;padding:.4em .6em;border-radius:3px}
#imgcheck{display:none}
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.dataset.imagesOk = ok + "/" + imgs.length;
  if (ok < imgs.length) {
    var w = document.getElementById("imgcheck");
    w.textContent = (imgs.length - ok) + " of " + imgs.length + " images could not be shown";
    w.style.display = "block";
  }
});
"""


def esc(v) -> str:
    return html.escape(str(v), quote=True)


def fmt(v, digits: int = 3) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        if v != 0 and abs(v) < 1:
            return f"{v:.4g}"
        return f"{v:.{digits}f}" if abs(v) < 1e5 else f"{v:.4g}"
    return str(v)


MIN_DISPLAY_WIDTH = 240  # tiny images are shown enlarged by an integer factor (pixelated), at least this wide


def _img(png_array: np.ndarray, alt: str, caption: str, extra: str = "") -> str:
    k = max(1, -(-MIN_DISPLAY_WIDTH // png_array.shape[1]))
    return (f'<figure><img src="{data_uri(encode_png(png_array))}" alt="{esc(alt)}" '
            f'width="{png_array.shape[1] * k}" height="{png_array.shape[0] * k}">'
            f"<figcaption>{esc(caption)}{extra}</figcaption></figure>")


_CBAR: str | None = None


def _colour_bar(vmax: float, kind: str) -> str:
    global _CBAR
    if _CBAR is None:
        _CBAR = data_uri(encode_png(colormap(np.tile(np.linspace(0, 1, 256), (8, 1)), 1.0)))
    return (f'<div class="cbar"><span>0</span><img src="{_CBAR}" alt="colour bar of {esc(kind)}">'
            f"<span>{esc(fmt(float(vmax), 3))}</span></div>")


def table(headers: list, rows: list[list]) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{esc(fmt(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def stage_bars(stage_ms: dict, scale_ms: float | None = None) -> str:
    """One horizontal bar per stage (milliseconds), the longest (or ``scale_ms``) 100 % wide."""
    items = [(k, float(v)) for k, v in stage_ms.items() if isinstance(v, (int, float)) and k != "total"]
    if not items:
        return ""
    top = max(scale_ms or 0.0, max(v for _, v in items), 1e-9)
    rows = "".join(f'<div class="bar"><span class="k">{esc(k)}</span><div style="width:{300 * v / top:.1f}px">'
                   f'</div><span class="v">{esc(fmt(v, 1))} ms</span></div>' for k, v in items)
    return f'<div class="bars">{rows}</div>'


def panel_html(p: FramePanel) -> str:
    parts = [f'<div class="frame"><h3>{esc(p.name)}</h3>']
    if p.note:
        parts.append(f'<p class="fail">{esc(p.note)}</p>')
    figs = []
    if p.rendered is not None:
        figs.append(_img(p.rendered, f"{p.name} rendered", "rendered"))
    if p.truth is not None:
        figs.append(_img(p.truth, f"{p.name} ground truth", "ground truth"))
    if p.error is not None:
        figs.append(_img(p.error, f"{p.name} error", f"error: {p.error_kind}", _colour_bar(p.error_max, p.error_kind)))
    if p.mask is not None:
        figs.append(_img(p.mask, f"{p.name} mask", p.mask_label))
    if p.hole is not None:
        figs.append(_img(p.hole, f"{p.name} holes", "holes (white)"))
    if figs:
        parts.append('<div class="imgs">' + "".join(figs) + "</div>")
    if p.numbers:
        parts.append(table(list(p.numbers), [list(p.numbers.values())]))
    parts.append(stage_bars(p.stage_ms))
    parts.append("</div>")
    return "".join(parts)


def page(title: str, body: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
            f'<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_CSS}</style></head>'
            f'<body><p id="imgcheck" class="fail"></p><h1>{esc(title)}</h1>{body}<script>{_SCRIPT}</script>'
            "</body></html>\n")


def check_output(path: str | os.PathLike, argument: str = "report_html") -> Path:
    """Fail early (before any rendering) when a file cannot be written at ``path`` (a
    directory; a parent that is a file; a folder this process may not write into); the error
    names the argument ``argument``."""
    p = Path(path)
    if p.is_dir():
        raise BadValueError.about(argument, "is a directory (give a file name)", str(p))
    probe = p.parent
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise BadValueError.about(argument, f"{probe} is not a directory", str(p))
    if not os.access(probe, os.W_OK | os.X_OK):
        raise BadValueError.about(argument, f"cannot write into {probe}", str(p))
    return p


def write_page(path: str | os.PathLike, text: str) -> Path:
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    except OSError as e:
        raise BadValueError(f"report {path}: cannot write ({e.strerror or e})") from None
    return path


# --- the two pages ------------------------------------------------------------------------------
_SHOWN_METRICS = ("psnr", "psnr_covered", "ssim", "flip", "coverage", "psnr_holes", "depth_psnr", "depth_ssim",
                  "hole_fraction")


def render_report(report: dict, out_dir: str | os.PathLike, path: str | os.PathLike, *,
                  truths: dict | None = None, max_frames: int = MAX_FRAMES, max_width: int = MAX_WIDTH,
                  title: str | None = None) -> Path:
    """The page of an ``ibr-render`` run: ``report`` as in report.json, images read from
    ``out_dir``; ``truths`` maps frame names to ground-truth linear images (or callables giving
    them) for the error maps. Returns the page's path."""
    out_dir = Path(out_dir)
    truths = truths or {}
    frames = list(report.get("frames") or [])
    shown = pick_frames(len(frames), max_frames)
    s = report.get("summary") or {}
    failed = report.get("failed") or [f for f in frames if f.get("error")]
    summary = [["method", report.get("method")], ["frames", s.get("frames", len(frames))],
               ["input views", report.get("inputs")], ["threads", report.get("threads")]]
    tm = s.get("time_ms") or {}
    summary += [["median ms per frame", tm.get("median")], ["total ms", tm.get("total")]]
    summary += [[k.replace("mean_", "mean "), v] for k, v in s.items() if k.startswith("mean_")]
    if failed:
        summary.append(["failed frames", len(failed)])
    if report.get("params"):
        summary.append(["parameters", ", ".join(f"{k}={v}" for k, v in report["params"].items())])
    if report.get("lightfield"):
        summary.append(["light field", ", ".join(f"{k}={v}" for k, v in report["lightfield"].items())])
    body = ["<h2>Summary</h2>", table(["", "value"], summary)]
    if s.get("setup_ms"):
        body.append("<p>setup (once per run)</p>" + stage_bars(s["setup_ms"]))
    if failed:
        items = "".join(f"<li>{esc(f.get('name', '?'))}: {esc(f.get('error', ''))}</li>" if isinstance(f, dict)
                        else f"<li>{esc(f)}</li>" for f in failed)
        body.append(f'<div class="fail">failed frames (not rendered; the others were):<ul>{items}</ul></div>')
    body.append("<h2>Frames</h2>")
    if len(shown) < len(frames):
        body.append(f'<p class="note">Showing {len(shown)} of {len(frames)} frames (evenly spaced, first and '
                    f"last included); every frame is in report.json.</p>")
    if any(f.get("image") for f in frames):
        body.append(f"<p>Images shrunk to at most {int(max_width)} pixels wide.</p>")
    for i in shown:
        f = frames[i]
        numbers = {k: f.get(k) for k in ("row", "col") if k in f}
        numbers.update({k: v for k, v in (f.get("metrics") or {}).items() if k in _SHOWN_METRICS})
        numbers["ms"] = (f.get("time_ms") or {}).get("total")
        stage = {k: v for k, v in (f.get("time_ms") or {}).items() if k != "total"}
        img = out_dir / str(f.get("image", ""))
        if not f.get("image") or not img.is_file():
            body.append(panel_html(FramePanel(str(f.get("name")), numbers=numbers,
                                              note=f"no image: {f.get('error', 'not written')}")))
            continue
        rendered = read_image(img)[..., :3]
        truth = truths.get(f.get("name"))
        truth = truth() if callable(truth) else truth
        selection = hole = None
        if f.get("method_mask") and (out_dir / f["method_mask"]).is_file():  # hybrid: the method choice
            selection = read_image(out_dir / f["method_mask"])[..., :3]
        if f.get("hole_mask"):
            hole = _read_mask(out_dir / f["hole_mask"])
        body.append(panel_html(frame_panel(f.get("name"), rendered, truth, selection=selection, hole=hole,
                                           stage_ms=stage, numbers=numbers, max_width=max_width)))
    t = title or f"ibr-render --method {report.get('method')}: {len(frames)} frame{'' if len(frames) == 1 else 's'}"
    return write_page(path, page(t, "".join(body)))


def _read_mask(path: Path) -> np.ndarray | None:
    if not path.is_file():
        return None
    m = read_image(path)
    return (m if m.ndim == 2 else m[..., 0]) > 0.5


