"""How much memory this process may still allocate: what every memory estimate (render jobs,
TSDF fusion, synthetic scenes, image decoding) is checked against before it allocates."""
from __future__ import annotations

import os
from pathlib import Path

from ibrtools.errors import BadValueError


def _parse_bytes(text: str) -> int:
    t = text.strip().upper().removesuffix("B")
    mult = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}.get(t[-1:], 1)
    try:
        v = float(t[:-1] if t[-1:] in "KMGT" else t) * mult
    except ValueError:
        raise BadValueError(f"IBR_MEMORY_LIMIT: expected a size such as 8G or 512M, got {text!r}") from None
    if not v > 0:
        raise BadValueError(f"IBR_MEMORY_LIMIT: expected a positive size, got {text!r}")
    return int(v)


def available_memory() -> int:
    """Bytes this process may still allocate: $IBR_MEMORY_LIMIT when set, else the smaller of
    MemAvailable (/proc/meminfo) and the cgroup v2 limit minus its usage (containers)."""
    env = os.environ.get("IBR_MEMORY_LIMIT")
    if env:
        return _parse_bytes(env)
    avail = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text())
            avail = min(avail or 1 << 62, int(limit) - used)
    except (OSError, ValueError):
        pass
    return avail if avail is not None else 1 << 62  # unknown platform: do not refuse
