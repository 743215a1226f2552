"""A job's output directory (``shotcrete demo`` / ``shotcrete plan --out OUT``): locked, written
into a temporary directory beside OUT and moved into place only when complete
(docs/architecture.md §10). Beside OUT, in its parent directory:

- ``.OUT.lock``: the lock (``flock``) of the job writing OUT; it holds ``pid, host, start`` of that
  job. A second job on OUT fails at once naming the holder; the kernel drops the lock of a killed
  job, and the next job takes the stale lock over with a warning.
- ``.OUT.tmp-XXXXXX``: the job's files while it runs; removed when the job fails, and by the next
  job on OUT when the job was killed.
- ``OUT.prev``: the previous complete set, kept as a backup when a job replaces OUT.

OUT therefore always holds one complete set (or none yet); the swap is two renames, and a job
killed between them leaves OUT missing with the previous set complete in OUT.prev.
"""
from __future__ import annotations

import datetime
import fcntl
import os
import shutil
import socket
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

MARKER = ".shotcrete-output"


class OutputLocked(ValueError):
    """Another job holds the lock of the output directory."""


def _warn(message: str) -> None:
    sys.stderr.write(f"warning: {message}\n")


def _ours(path: Path) -> bool:
    """``path`` is missing, an empty directory, or a directory shotcrete wrote."""
    return not path.exists() or (path.is_dir() and (not any(path.iterdir()) or (path / MARKER).exists()))


def _check_target(out: Path, prev: Path, inputs: Iterable[Path]) -> None:
    if out == out.parent:
        raise ValueError(f"output directory {out} is a file system root; choose a directory below it")
    if out.exists() and not out.is_dir():
        raise ValueError(f"output path {out} exists and is not a directory")
    if not _ours(out):
        raise ValueError(f"output directory {out} is not empty and was not written by shotcrete; "
                         "choose another --out so nothing of yours is overwritten")
    if not _ours(prev):
        raise ValueError(f"{prev} (where the previous result of {out} is kept) exists and was not written "
                         "by shotcrete; move it away or choose another --out")
    for p in inputs:
        p = Path(p).resolve()
        if p.is_relative_to(out) or p.is_relative_to(prev):
            raise ValueError(f"input {p} lies in the output directory {out}; choose another --out")


def _read_holder(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    return os.read(fd, 4096).decode("utf-8", "replace").strip()


def _acquire(out: Path) -> tuple[int, Path]:
    """The lock of ``out`` (an open, flock-ed descriptor); OutputLocked when another job holds it."""
    path = out.parent / f".{out.name}.lock"
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd) or "a job that is just starting"
            os.close(fd)
            raise OutputLocked(f"output directory {out} is in use by another shotcrete job ({holder}); "
                               f"wait for it to finish or choose another --out (lock file {path})") from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # its holder removed the file between our open and flock: lock the new one
    stale = _read_holder(fd)
    if stale:
        _warn(f"took over the stale lock of {out} ({stale}): that job ended without finishing")
    started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    os.ftruncate(fd, 0)
    os.write(fd, f"pid {os.getpid()} on host {socket.gethostname()}, started {started}\n".encode())
    return fd, path


def _release(fd: int, path: Path) -> None:
    """Remove the lock file while still holding it (a job that opened it meanwhile sees another
    inode and retries), then unlock."""
    try:
        os.unlink(path)
    finally:
        os.close(fd)


def _remove_leftovers(out: Path) -> None:
    """Temporary directories of earlier jobs on ``out`` that were killed (we hold the lock)."""
    for p in out.parent.iterdir():
        if p.name.startswith((f".{out.name}.tmp-", f".{out.name}.old-")) and p.is_dir():
            _warn(f"removing {p}, the unfinished output of an earlier job that was killed")
            shutil.rmtree(p)


def _swap(tmp: Path, out: Path, prev: Path) -> None:
    """``tmp`` becomes ``out``; the set ``out`` held becomes ``prev`` (the older backup is dropped)."""
    if out.is_dir() and any(out.iterdir()):
        trash = None
        if prev.exists():
            trash = out.parent / f".{out.name}.old-{os.getpid()}"
            os.rename(prev, trash)
        os.rename(out, prev)
        os.rename(tmp, out)
        if trash is not None:
            shutil.rmtree(trash, ignore_errors=True)
    else:
        os.rename(tmp, out)  # replaces an empty directory atomically


@contextmanager
def job_output(out: Path, inputs: Iterable[Path] = ()) -> Iterator[Path]:
    """Lock ``out`` and yield a fresh temporary directory beside it to write the job's files into;
    on leaving without an exception it replaces ``out`` (the previous set becomes ``out.prev``), on
    an exception it is removed and ``out`` is left as it was. ValueError (exit 2 on the CLI) when
    ``out`` is not ours to replace, when an input lies in it, or when another job holds it."""
    out, inputs = Path(out).resolve(), list(inputs)
    prev = out.with_name(out.name + ".prev")
    _check_target(out, prev, inputs)
    for above in out.parents:
        if above.exists() or above.is_symlink():
            if not above.is_dir():
                raise ValueError(f"output directory {out} lies under {above}, which is not a directory")
            break
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, lock_path = _acquire(out)
    try:
        _check_target(out, prev, inputs)  # again, now that no other job can change it
        _remove_leftovers(out)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
        try:
            umask = os.umask(0o022)
            os.umask(umask)
            tmp.chmod(0o777 & ~umask)  # as a plain mkdir would (mkdtemp makes it private)
            (tmp / MARKER).write_text("written by shotcrete-planner; files here may be replaced by the next run\n")
            yield tmp
            _swap(tmp, out, prev)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    finally:
        _release(fd, lock_path)
