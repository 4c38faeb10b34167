"""What every benchmark script shares: timing (median after a warm-up), the machine's
description, replacing one marked section of docs/benchmarks.md, and where the shared real data is."""
from __future__ import annotations

import os
import platform
import re
import statistics
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def shared_data() -> Path:
    """The real test data: $IBR_SHARED_DATA, else ../shared/data beside the repository."""
    env = os.environ.get("IBR_SHARED_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"


def median_ms(fn, repeats: int, warmup: bool = True) -> float:
    """Median wall time of ``fn()`` in milliseconds over ``repeats`` calls (after one warm-up
    call that starts the thread pool and touches the memory)."""
    if warmup:
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def machine() -> str:
    """One phrase for the write-up: CPU, cores, Python."""
    return f"{cpu_name()} ({os.cpu_count()} cores), Python {platform.python_version()}"


def write_section(name: str, section: str, path: Path = DOCS) -> None:
    """Replace (or append) the section between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->``."""
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    block = f"{begin}\n{section.rstrip()}\n{end}\n"
    text = path.read_text() if path.exists() else "# Benchmarks\n\n"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end) + r"\n?", re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip("\n") + "\n\n" + block
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def load_note() -> str:
    """The closing line of a section: how busy the machine was (ratios stay meaningful)."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"1-minute load average at the end of the run: {load:.2f} (other work on the machine slows "
            "every row alike; read the ratios).")


def size_repeats_main(doc: str, section: str, run, argv=None, *, min_size: int = 7) -> int:
    """The command line shared by the image benchmarks: --size, --repeats, --write [FILE]."""
    import argparse

    p = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, default=1024, help="image side in pixels (default 1024)")
    p.add_argument("--repeats", type=int, default=7, help="timed runs per case, >= 5 (default 7)")
    p.add_argument("--write", type=Path, nargs="?", const=DOCS,
                   help=f"replace or append this benchmark's section of a Markdown file (default {DOCS.name})")
    args = p.parse_args(argv)
    if args.size < min_size or args.repeats < 5:
        p.error(f"--size must be >= {min_size} and --repeats >= 5")
    text = run(args.size, args.repeats)
    print(text)
    if args.write:
        write_section(section, text, args.write)
    return 0
