"""Preprocessing stages and their planner (DESIGN.md "Skip what a scene does not need").

A stage declares what it reads and what it is for; the planner runs it only when its
output is missing or its inputs or parameters changed (a content hash, stored in the
scene's ``scene.json`` under ``stages``), and reports every stage as ran / up to date /
skipped, with the reason and the time. Today the only stage is ``import``; the hybrid-IBR
stages (depth from mesh, fusion, textures, per-view meshes, harmonisation) join this table.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from .errors import BadValueError, InputError
from .scene import Scene

# Bump when the import code changes what it writes, so that old scenes are rebuilt.
IMPORT_STAGE_VERSION = 1
_HASH_CHUNK = 1 << 20


@dataclass
class StageResult:
    name: str
    status: str  # "ran" | "up to date" | "skipped" | "failed"
    reason: str
    seconds: float = 0.0
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"stage": self.name, "status": self.status, "reason": self.reason,
                "seconds": round(self.seconds, 4), **self.details}


def hash_inputs(path: Path, params: dict) -> str:
    """Content hash of a file or a directory tree (relative names and bytes) and ``params``."""
    h = hashlib.blake2b(digest_size=16)
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    path = Path(path)
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        rel = f.name if f == path else f.relative_to(path).as_posix()
        h.update(rel.encode() + b"\0")
        with open(f, "rb") as fh:
            while chunk := fh.read(_HASH_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def _existing_record(output: Path, stage: str) -> dict | None:
    f = output / "scene.json"
    if not f.is_file():
        return None
    try:
        with open(f, encoding="utf-8") as fh:
            return (json.load(fh).get("stages") or {}).get(stage)
    except (OSError, ValueError, AttributeError):
        return None  # unreadable: treat as absent and rebuild


def run_import(input_spec: str, output: Path, *, fmt: str | None = None, options: dict | None = None,
               synth: dict | None = None, force: bool = False) -> StageResult:
    """The ``import`` stage: read a data set (or make a synthetic one), validate it, write the
    native scene. Up to date when ``output`` holds a scene made from the same input bytes and
    parameters."""
    from .formats import load as load_dataset
    from .formats import native

    options = dict(options or {})
    output = Path(output)
    if synth is not None:
        params = {"synth": synth, "version": IMPORT_STAGE_VERSION}
        key = hashlib.blake2b(json.dumps(params, sort_keys=True).encode(), digest_size=16).hexdigest()
    else:
        src = Path(input_spec)
        if src.resolve() == output.resolve():
            raise BadValueError(f"-o {output}: output is the input; choose another directory")
        params = {"format": fmt, "options": options, "version": IMPORT_STAGE_VERSION}
        key = hash_inputs(src, params)
    record = _existing_record(output, "import")
    if not force and record and record.get("key") == key:
        return StageResult("import", "up to date", "inputs and parameters unchanged", 0.0,
                           {"views": record.get("views"), "targets": record.get("targets")})
    t0 = time.perf_counter()
    if synth is not None:
        from .synth import make_scene

        scene: Scene = make_scene(**synth)
        fmt_used = f"synth:{synth['preset']}"
    else:
        scene = load_dataset(Path(input_spec), fmt, options)
        fmt_used = scene.source.get("format", fmt)
    n_views, n_targets = len(scene.views), len(scene.targets)
    scene.stages["import"] = {"key": key, "format": fmt_used, "views": n_views, "targets": n_targets,
                              "seconds": round(time.perf_counter() - t0, 4)}
    native.save(scene, output)
    seconds = time.perf_counter() - t0
    reason = "forced" if force else ("inputs changed" if record else "no scene yet")
    return StageResult("import", "ran", f"{reason}; {fmt_used}", seconds,
                       {"views": n_views, "targets": n_targets})


def parse_options(pairs: list[str] | None) -> dict:
    """``key=value`` strings (``--opt``) into a dict; numbers stay strings (importers convert)."""
    out: dict = {}
    for p in pairs or []:
        if "=" not in p or not p.split("=", 1)[0]:
            raise InputError(f"--opt {p!r}: expected key=value")
        k, v = p.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def preprocess(input_spec: str, output: str | os.PathLike, *, fmt: str | None = None,
               options: dict | None = None, synth: dict | None = None,
               force: bool = False) -> list[StageResult]:
    """Run the stages a scene needs; returns the stage table."""
    return [run_import(input_spec, Path(output), fmt=fmt, options=options, synth=synth, force=force)]
