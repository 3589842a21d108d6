"""The SDP backends by name: ``SolverConfig.backend`` "NAME" or "NAME:ARG" selects ``BACKENDS[NAME]``.

A backend is a small object with these attributes and methods (``backend.Backend``):
``name``; ``decompose_default`` (what ``SolverConfig.decompose = None`` means); ``cover`` (the cover
policy of ``covers.CliqueCovers.choose``, or None when it takes no cover); ``fallback`` (the backend
that solves again when a result is unusable, or None); ``retries(config, decomposed, N)`` (the
configs to try, in order, each as (what, config, statuses): tried when the result so far has one
of those statuses);
``errors`` (exceptions the solver legitimately raises, turned into a "Failed" status; anything else
propagates); ``check(arg)`` (SolverConfigError when it is unusable, e.g. not installed);
``solve(Q, As, b, d, cliques, config) -> SDPResult``.

This module only holds the table; ``autotight.sdp`` (the package's ``__init__``, which runs before any of
its modules is used) fills it with the shipped backends.  A backend of one's own is one more entry:
``BACKENDS["mysolver"] = MySolverBackend()``.
"""

from __future__ import annotations

from typing import Any

#: name → backend (a ``backend.Backend``; filled by ``autotight.sdp``)
BACKENDS: dict[str, Any] = {}
