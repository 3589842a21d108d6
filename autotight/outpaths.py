"""Output paths: checked before the work starts, written atomically, locked while a run uses them.

``check_file`` (``discover --out``) and ``check_folder`` (``report --out``) refuse, before any
work, an empty path, a file where a folder is needed (or the reverse), a path inside a file, a
place that cannot be written, and a disk with less than ``MIN_FREE_BYTES`` free; ``check_file``
also refuses to replace an existing file unless asked (``force``).  ``writing`` turns an OSError
while writing (a full disk, a read-only folder) into a one-line ``OutputError``.  ``folder_lock``
holds an exclusive ``fcntl.flock`` on ``FOLDER/.lock`` so that two runs never write one folder.
``save_json`` writes a result file the user named without ever replacing one that appeared meanwhile.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator

from .errors import AutotightError

#: free space needed where an output goes (the first write of a report or a discovered set is ~100 kB)
MIN_FREE_BYTES = 1 << 20
LOCK_NAME = ".lock"


class OutputError(AutotightError):
    """An output path that cannot or must not be written."""


def _nearest_existing(path: Path, option: str, given: Path) -> Path:
    """The deepest existing ancestor of ``path`` (itself included); it must be a folder."""
    for p in [path, *path.parents]:
        if p.exists():
            if not p.is_dir():
                raise OutputError(f"{option} {given}: {p} is a file, not a folder")
            return p
    return Path(".")


def _check_writable(folder: Path, option: str, path: Path) -> None:
    """Create and delete a temporary file in ``folder``; then check its free space."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        raise OutputError(f"{option} {path}: cannot write in {folder} ({e.strerror or e})") from None
    free = shutil.disk_usage(folder).free
    if free < MIN_FREE_BYTES:
        raise OutputError(f"{option} {path}: only {free} bytes free on the disk of {folder} "
                          f"(need at least {MIN_FREE_BYTES // 1024} kB)")


def _nonempty(path: str | os.PathLike, option: str) -> Path:
    if not str(path).strip():
        raise OutputError(f"{option} '': give a path")
    return Path(path)


def check_file(path: str | os.PathLike, *, option: str = "--out", force: bool = False) -> Path:
    """A file that may be written: not a folder, not inside a file, writable, with disk space;
    an existing file only with ``force``."""
    p = _nonempty(path, option)
    if p.is_dir() or str(path).endswith(os.sep):
        raise OutputError(f"{option} {path}: is a folder; give a file name")
    if p.exists() and not force:
        raise OutputError(f"{option} {path}: exists; give --force to overwrite it")
    folder = _nearest_existing(p.parent, option, p)
    _check_writable(folder, option, p)
    return p


def check_folder(path: str | os.PathLike, *, option: str = "--out") -> Path:
    """A folder that may be created or written: not a file, not inside a file, writable, with disk space."""
    p = _nonempty(path, option)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{option} {path}: is a file, not a folder")
    _check_writable(_nearest_existing(p, option, p), option, p)
    return p


@contextlib.contextmanager
def writing(path: str | os.PathLike) -> Iterator[None]:
    """Turn an OSError raised while writing ``path`` into an ``OutputError`` (a full disk, no permission)."""
    try:
        yield
    except OSError as e:
        what = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
        raise OutputError(f"cannot write {path}: {what}") from e


def save_json(path: str | os.PathLike, obj: Any, *, replace: bool = False, what: str = "the result") -> Path:
    """Write ``obj`` as JSON to a file the user named (``io.write_json``): a folder or an empty path is an
    ``OutputError``; replace=False never writes over a file that exists (the result is kept beside it,
    with a warning saying where); an OSError while writing (no permission, a full disk) is an
    ``OutputError``.  Returns the path written."""
    from .io import write_json

    if not str(path).strip():
        raise OutputError(f"cannot save {what}: give a file name, not ''")
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"cannot save {what} to {p}: it is a folder; give a file name")
    _nearest_existing(p.parent, "cannot save to", p)  # a path inside a file
    with writing(p):
        return write_json(p, obj, replace=replace)


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, what: str = "autotight report") -> Iterator[Path]:
    """Create ``folder`` if needed and hold an exclusive lock on ``folder/.lock`` (Unix; elsewhere no lock)."""
    folder = Path(folder)
    with writing(folder):
        folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    try:
        import fcntl
    except ImportError:  # not on Unix
        yield path
        return
    with writing(path):
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
            raise OutputError(f"another {what} is writing {folder} (pid {holder or '?'}); wait for it to finish "
                              "or use another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode("ascii"), 0)
        yield path
    finally:
        os.close(fd)  # releases the lock
