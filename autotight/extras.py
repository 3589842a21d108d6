"""Optional features and the pip extra that installs each one.

The core library (solve, discover, check) needs only the hard dependencies.  A feature that
needs an extra calls :func:`require` first, so a missing package is one clear error naming the
extra, never an ImportError deep inside the feature or a CLI verb that silently disappears.
"""

from __future__ import annotations

from importlib.util import find_spec

from .errors import AutotightError

EXTRAS: dict[str, tuple[str, ...]] = {
    "report": ("pandas", "matplotlib", "joblib"),
    "dask": ("distributed",),
}


class MissingExtraError(AutotightError):
    """A feature's optional packages are not installed."""


def missing(extra: str) -> list[str]:
    """The import names of ``extra``'s packages that cannot be imported."""
    out = []
    for name in EXTRAS[extra]:
        try:
            found = find_spec(name) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            out.append(name)
    return out


def require(extra: str, feature: str) -> None:
    """Raise :class:`MissingExtraError` if ``feature`` cannot run because ``extra`` is not installed."""
    lack = missing(extra)
    if lack:
        raise MissingExtraError(f"{feature} needs {', '.join(lack)}, which is not installed: "
                                f"pip install 'autotight[{extra}]'")
