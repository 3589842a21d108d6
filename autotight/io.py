"""Results as data: JSON conversion, versions, atomic writes."""

from __future__ import annotations

import json
import os
import platform
import tempfile
import warnings
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

PACKAGES = ("numpy", "scipy", "clarabel", "cvxpy", "qdldl", "numba", "pandas")


def versions() -> dict[str, str]:
    """Python, autotight (its ``__version__``, the one version source) and the numerical packages."""
    from ._version import __version__

    out = {"python": platform.python_version(), "autotight": __version__}
    for p in PACKAGES:
        try:
            out[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            out[p] = "not installed"
    return out


def jsonable(obj: Any) -> Any:
    """Arrays → nested lists, numpy scalars → Python scalars, non-finite floats → strings."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind in "biu" or (obj.dtype.kind == "f" and np.isfinite(obj).all()):
            return obj.tolist()  # Python ints, floats and bools already
        return jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if np.isfinite(f) else str(f)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _umask() -> int:
    """The process's umask (read without changing it where /proc allows)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _beside(path: Path, k: int) -> Path:
    """NAME.k.EXT beside ``path`` (NAME.k without an extension)."""
    return path.with_name(f"{path.stem}.{k}{path.suffix}") if path.suffix else path.with_name(f"{path.name}.{k}")


def _link_new(tmp: str, path: Path) -> bool:
    """Put ``tmp`` at ``path`` only if ``path`` does not exist (a hard link, else an exclusive create);
    False when it exists."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        return False
    except OSError:  # no hard links here: reserve the name exclusively, then move over the reservation
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return False
        os.replace(tmp, path)
        return True
    os.unlink(tmp)
    return True


def atomic_write_text(path: str | Path, text: str, *, replace: bool = True) -> Path:
    """Write to a temporary file in the same folder, then move it into place: never a half-written file.

    replace=True: the file replaces whatever is at ``path``.  replace=False: it is linked into place
    only if ``path`` still does not exist at that moment; otherwise it is kept beside it as
    NAME.1.EXT (the first free NAME.k.EXT) and a warning says where.  Returns the path written.
    The file gets the permissions of a newly created one (0o666 less the umask).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        if replace:
            os.replace(tmp, path)
            return path
        target, k = path, 0
        while not _link_new(tmp, target):
            k += 1
            target = _beside(path, k)
        if target != path:
            warnings.warn(f"{path} exists and is kept; the result is saved beside it as {target}", stacklevel=3)
        return target
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_json(path: str | Path, obj: Any, *, replace: bool = True) -> Path:
    """``obj`` as indented JSON (``jsonable``) by ``atomic_write_text``; returns the path written."""
    return atomic_write_text(path, json.dumps(jsonable(obj), indent=1, ensure_ascii=False) + "\n", replace=replace)
