"""Output directories and temporary files: where a job may write, and what it owns there.

- Frame names become file names through :func:`file_stem`: a name from a scene or a pose file
  (``"train/r_0"``, ``"../victim"``, ``"/abs/path"``) is mapped to one plain path component, so
  nothing is ever written outside the output directory.
- :func:`check_output_dir` refuses an output directory that is empty, is a scene or lies inside
  one (a render must never replace a scene's own inputs).
- :class:`OutputDir` locks an output directory for the duration of a job (a second job gets a
  one-line error naming the holder), keeps a journal of the files the job writes (in the lock
  file), and on entry sweeps the temporaries of a job that died there (SIGKILL) and reads which
  files an earlier job left (:attr:`OutputDir.previous`), so a re-run can say which of them it
  replaced or removed.
- Temporaries carry the process's own mark (:func:`temp_prefix`), so a job's cleanup never
  touches another job's files, and every file and directory is created with the mode the umask
  gives (``tempfile`` makes them 0600 / 0700).
"""
from __future__ import annotations

import fcntl
import json
import os
import re
import secrets
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

from ibrtools.errors import BadValueError

LOCK_NAME = ".ibr-lock"
_UNSAFE = set('/\\:*?"<>|')
MAX_STEM = 200  # characters: with the longest suffix (".depth.exr") well under NAME_MAX (255 bytes)
# A temporary's mark: ".<stem>.ibrtmp-<pid>-<hex>.<random><suffix>" (files) or the same without
# the suffix (directories).
_TEMP_RE = re.compile(r"^\..*\.ibrtmp-(\d+)-[0-9a-f]{6}\.")
_token: tuple[int, str] | None = None


def _umask() -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)  # read once at import, before any thread of ours runs
    os.umask(old)
    return old


UMASK = _umask()


def file_stem(name: str) -> str:
    """The file-name stem of a frame called ``name``: one plain path component. Path
    separators, characters Windows refuses, control characters and a leading dot (hidden
    files, and our temporaries) become "_"; at most :data:`MAX_STEM` characters; never empty.
    A plain name (``v003``, ``orbit_0001``) is its own stem."""
    s = "".join("_" if c in _UNSAFE or ord(c) < 32 or ord(c) == 127 else c for c in str(name))
    if s.startswith("."):
        s = "_" + s[1:]
    return s[:MAX_STEM] or "_"


def _mark() -> str:
    global _token
    if _token is None or _token[0] != os.getpid():  # a forked child gets its own mark
        _token = (os.getpid(), secrets.token_hex(3))
    return f"ibrtmp-{_token[0]}-{_token[1]}"


def is_plain_name(name: str) -> bool:
    """True for one path component that is not hidden: what every file a job writes in its
    output directory is called (file_stem's stems with their suffixes)."""
    return bool(name) and name == Path(name).name and not name.startswith(".") and name not in (".", "..")


def temp_prefix(stem: str) -> str:
    """The prefix of this process's temporaries beside a file ``stem``: the process id and a
    random tag, so that two jobs (or a job and the sweep of a dead one) never take each
    other's temporaries for their own."""
    return f".{stem}.{_mark()}."


def mkstemp_beside(path: Path) -> Path:
    """A new empty temporary file beside ``path`` (same suffix), mode as the umask gives."""
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path.stem), suffix=path.suffix, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~UMASK)
    finally:
        os.close(fd)
    return Path(tmp)


def mkdtemp_beside(path: Path, tag: str = "") -> Path:
    """A new empty temporary directory beside ``path``, mode as the umask gives."""
    tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(path.name + tag), dir=path.parent))
    os.chmod(tmp, 0o777 & ~UMASK)
    return tmp


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_temporaries(directory: Path, stems: set[str] | None = None, prefix: str = ".") -> list[str]:
    """Remove the temporaries in ``directory`` left by processes that no longer run (killed
    before they could clean up) and return their names. ``stems``: also the unmarked
    temporaries (".<stem>.XXXXXXXX<suffix>", as written before they carried a mark) of these
    file stems, which only a dead job can have left when the caller holds the directory's lock.
    ``prefix``: only names that start with it."""
    swept = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return swept
    old = re.compile(r"^\.(.+)\.[a-z0-9_]{8}(\.[A-Za-z0-9]+)?$")  # tempfile's 8 random characters
    for e in entries:
        if not e.name.startswith(prefix):
            continue
        m = _TEMP_RE.match(e.name)
        if m:
            dead = not _alive(int(m.group(1)))
        elif stems is not None and (o := old.match(e.name)) and e.is_file(follow_symlinks=False):
            dead = o.group(1) in stems
        else:
            continue
        if not dead:
            continue
        try:
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path)
            else:
                os.unlink(e.path)
            swept.append(e.name)
        except OSError:
            pass
    return sorted(swept)


def _scene_root_of(path: Path) -> Path | None:
    """The native scene directory ``path`` is or lies in (a directory with an ibrtools
    scene.json), else None."""
    for p in (path, *path.parents):
        f = p / "scene.json"
        try:
            if f.is_file() and b'"ibrtools-scene"' in f.read_bytes()[:4096]:
                return p
        except OSError:
            continue
    return None


def check_output_dir(out_dir: str | os.PathLike, flag: str = "-o") -> Path:
    """``out_dir`` as a Path after refusing what would write where it must not: an empty name
    (the current directory, by accident), an existing file, a scene directory or a directory
    inside one (its images or targets would be replaced by renders)."""
    if str(out_dir).strip() == "":
        raise BadValueError(f"{flag}: empty; give an output directory")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise BadValueError(f"{flag} {out}: exists and is not a directory")
    scene = _scene_root_of(out.resolve())
    if scene is not None:
        where = "is the scene" if scene == out.resolve() else f"lies inside the scene {scene}"
        raise BadValueError(f"{flag} {out}: {where}; a job never writes into a scene (its inputs could be "
                            "overwritten): choose a directory outside it")
    return out


class OutputDir:
    """``with OutputDir(path, command) as od:`` holds ``path`` for one job.

    On entry: the directory is created, locked (``.ibr-lock``, an advisory ``flock``: released
    by the kernel when the process ends however it ends; the file is removed when the job ends
    and outlives only a killed job), the temporaries of dead jobs are swept
    (:attr:`swept`), and :attr:`previous` is the set of files a killed job in this directory
    wrote (its journal in the lock file). ``record(name)`` adds a file to this job's journal as
    it is written."""

    def __init__(self, path: str | os.PathLike, command: str | None = None, *, flag: str = "-o",
                 stems: set[str] | None = None, lock: Path | None = None,
                 sweep: Callable[[], list[str]] | None = None):
        self.path = Path(path)
        self._sweep = sweep if sweep is not None else (lambda: sweep_temporaries(self.path, stems))
        self.lock = Path(lock) if lock is not None else self.path / LOCK_NAME
        self.command = command or " ".join(os.path.basename(a) if i == 0 else a for i, a in enumerate(sys.argv))
        self.flag = flag
        self._fd: int | None = None
        self._created = False
        self.swept: list[str] = []
        self.previous: set[str] = set()

    def __enter__(self) -> "OutputDir":
        self._created = not self.path.exists()
        while True:
            try:
                self.lock.parent.mkdir(parents=True, exist_ok=True)
                fd = os.open(self.lock, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as e:
                raise BadValueError(f"{self.flag} {self.path}: cannot write into it ({e.strerror or e})") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = _read_journal(fd)[0]
                os.close(fd)
                who = (f"pid {holder.get('pid')}: {holder.get('command', '?')}, since {holder.get('started', '?')}"
                       if holder else "another process")
                raise BadValueError(f"{self.flag} {self.path}: in use by another job ({who}); wait for it to end "
                                    "or choose another output directory") from None
            try:  # the holder before us may have removed the file between our open and our lock
                same = os.fstat(fd).st_ino == os.stat(self.lock).st_ino
            except OSError:
                same = False
            if same:
                break
            os.close(fd)
        self._fd = fd
        try:
            _, files = _read_journal(fd)
            self.previous = set(files)
            self.swept = self._sweep()
            head = {"pid": os.getpid(), "command": self.command[:500],
                    "started": time.strftime("%Y-%m-%d %H:%M:%S")}
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(head) + "\n").encode(), 0)
            os.lseek(fd, 0, os.SEEK_END)  # record() appends after the header
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def record(self, name: str) -> None:
        """Journal ``name`` (a file in the directory) as written by this job."""
        if self._fd is not None:
            os.write(self._fd, (json.dumps(name) + "\n").encode())

    def __exit__(self, *exc) -> None:
        """Release: the lock file is removed (while still held; a job that starts meanwhile sees
        its inode go and opens a new one), so it outlives only a job that was killed, whose
        journal the next job reads. A directory this job created and left empty goes too."""
        if self._fd is None:
            return
        try:
            self.lock.unlink(missing_ok=True)
            if self._created and self.lock.parent == self.path and not any(os.scandir(self.path)):
                self.path.rmdir()  # a job that failed before writing anything leaves no directory
        except OSError:
            pass
        finally:
            os.close(self._fd)
            self._fd = None


def scene_lock(scene: str | os.PathLike, command: str | None = None) -> OutputDir:
    """The lock of a scene directory that a job writes (``ibr-preprocess -o SCENE``): a file
    ``.<name>.ibr-lock`` beside it (the import replaces the whole directory by a rename), held
    like :class:`OutputDir`'s. On entry it sweeps what a killed run on this scene left: its marked
    temporaries beside the scene, in it and in its cache, and the unmarked scene directories
    (".<name>.XXXXXXXX", ".<name>.old.XXXXXXXX") that imports made before temporaries carried a
    mark; :attr:`OutputDir.swept` names them."""
    scene = Path(scene)
    return OutputDir(scene, command, lock=scene.parent / f".{scene.name}.ibr-lock",
                     sweep=lambda: _sweep_scene(scene))


def _sweep_scene(scene: Path) -> list[str]:
    swept = []
    old = re.compile(rf"^\.{re.escape(scene.name)}\.(old\.)?[a-z0-9_]{{8}}$")
    try:
        for e in os.scandir(scene.parent):
            if old.match(e.name) and e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path, ignore_errors=True)
                swept.append(e.name)
    except OSError:
        pass
    swept += sweep_temporaries(scene.parent, prefix=f".{scene.name}.")
    if scene.is_dir():
        swept += sweep_temporaries(scene)
        cache = scene / "cache"
        for d in sorted(cache.iterdir()) if cache.is_dir() else []:
            if d.is_dir():
                swept += [f"cache/{d.name}/{n}" for n in sweep_temporaries(d)]
    return sorted(swept)


def _read_journal(fd: int) -> tuple[dict, list[str]]:
    """(holder header, files) of a lock file; a torn or foreign file gives what parses."""
    try:
        size = os.fstat(fd).st_size
        text = os.pread(fd, min(size, 64 << 20), 0).decode("utf-8", "replace")
    except OSError:
        return {}, []
    head: dict = {}
    files: list[str] = []
    for i, line in enumerate(text.splitlines()):
        try:
            v = json.loads(line)
        except ValueError:
            continue
        if i == 0 and isinstance(v, dict):
            head = v
        elif isinstance(v, str) and is_plain_name(v):
            files.append(v)
    return head, files
