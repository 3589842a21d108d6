"""The fields of a saved constraint set (``discover --out``, docs/constraint_sets.md), checked on load.

``check_set_file(path)`` reads a set file's JSON and refuses, with one line naming the option, a file that
is missing, unreadable, not an object, of another ``format``, without ``problem`` or ``pairs``, or with a
malformed field (below).

``check_fields(obj)`` returns the first problem of a set file's JSON object as one line, or "" when
every field it reads is well formed:

- ``seed``: null or an int ≥ 0; ``d``: null or an int ≥ 1; ``params``: an object; ``info``: an object
  (``info.range.over``: {parameter: [values]});
- ``groups``: a spec string or a list of block-name lists;
- ``learn_options``: known names (``LearnOptions``) with finite values in range; ``heldout_tol`` in (0, 1)
  (a relative violation never exceeds 1, so 1 would accept every constraint);
- ``templates``: each of kind "polynomial" (the default) or "transport", with its factor type, identities,
  roles and block sizes; a polynomial template's ``degree`` in ``templates.DEGREES``, ``support``
  positions inside the type's k·m coefficient vector and a finite ``W`` of n_features(n_data, degree)
  rows by |support| columns; a transport template's finite ``data`` (n_data entries) and
  ``basis_triplets`` [μ, q, value] inside its m × n_relations basis;
- every (factor type, identity) of a template is one of ``pairs`` (templates outside them would be applied
  all the same); ``fallback`` maps factor types to text.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from .errors import ParameterError



def _int(v: Any, low: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= low


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _strings(v: Any, nonempty: bool = True) -> bool:
    return isinstance(v, list) and (bool(v) or not nonempty) and all(isinstance(x, str) for x in v)


def _learn_options(opts: dict[str, Any]) -> str:
    from .discovery.learn import LearnOptions

    known = {f.name for f in dataclasses.fields(LearnOptions)}
    unknown = sorted(set(opts) - known)
    if unknown:
        return f"unknown learn option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
    for k, v in opts.items():
        if k == "spread" and v is None:
            continue
        if k == "heldout":
            if not _int(v, 1):
                return f"learn option heldout must be an int ≥ 1, got {v!r}"
        elif not _finite(v) or v <= 0:
            return f"learn option {k} must be a finite number > 0, got {v!r}"
        elif k == "heldout_tol" and v >= 1:
            return f"learn option heldout_tol must be below 1 (a relative violation never exceeds 1), got {v!r}"
    return ""


def _template(t: Any, i: int) -> str:
    from .discovery.templates import DEGREES, n_features

    where = f"template {i}"
    if not isinstance(t, dict):
        return f"{where} must be an object"
    kind = t.get("kind", "polynomial")
    if kind not in ("polynomial", "transport"):
        return f"{where}: kind must be 'polynomial' or 'transport', got {kind!r}"
    if not isinstance(t.get("factor_type"), str):
        return f"{where}: factor_type must be text"
    where = f"template {i} ({t['factor_type']})"
    if not _strings(t.get("identities")) or not _strings(t.get("roles")):
        return f"{where}: identities and roles must be non-empty lists of text"
    sizes = t.get("block_sizes")
    if not isinstance(sizes, list) or not sizes or not all(_int(s, 1) for s in sizes):
        return f"{where}: block_sizes must be a list of ints ≥ 1"
    if not _int(t.get("n_data"), 0):
        return f"{where}: n_data must be an int ≥ 0, got {t.get('n_data')!r}"
    n = sum(sizes)
    m = n * (n + 1) // 2
    k = len(t["identities"])
    support = t.get("support")
    if not isinstance(support, list) or not all(_int(s, 0) for s in support):
        return f"{where}: support must be a list of ints ≥ 0"
    if kind == "transport":
        data = t.get("data")
        if not isinstance(data, list) or len(data) != t["n_data"] or not all(_finite(x) for x in data):
            return f"{where}: data must be {t['n_data']} finite numbers"
        r = t.get("n_relations")
        if not _int(r, 0):
            return f"{where}: n_relations must be an int ≥ 0"
        for key in ("free", "want"):
            if not isinstance(t.get(key), list) or not all(_int(x, 0) for x in t[key]):
                return f"{where}: {key} must be a list of ints ≥ 0"
        trip = t.get("basis_triplets")
        if not isinstance(trip, list) or not all(
                isinstance(x, list) and len(x) == 3 and _int(x[0], 0) and x[0] < m and _int(x[1], 0) and x[1] < r
                and _finite(x[2]) for x in trip):
            return f"{where}: basis_triplets must be [μ < {m}, q < {r}, finite value] triplets"
        return ""
    degree = t.get("degree")
    if not _int(degree, 0) or degree not in DEGREES:
        return f"{where}: degree must be one of {', '.join(map(str, DEGREES))}, got {degree!r}"
    if any(s >= k * m for s in support):
        return f"{where}: support positions must be below {k * m} ({k} identities × {m} monomials)"
    W = t.get("W")
    rows = n_features(t["n_data"], degree)
    if not isinstance(W, list) or len(W) != rows or not all(
            isinstance(row, list) and len(row) == len(support) and all(_finite(x) for x in row) for row in W):
        return (f"{where}: W must be {rows} rows of {len(support)} finite numbers (n_data {t['n_data']}, "
                f"degree {degree})")
    return ""


def check_fields(obj: dict[str, Any]) -> str:
    """The first malformed field of a set file's JSON object, as one line (module docstring), or ""."""
    seed = obj.get("seed")
    if seed is not None and not _int(seed, 0):
        return f"'seed' must be null or an int ≥ 0, got {seed!r}"
    d = obj.get("d")
    if d is not None and not _int(d, 1):
        return f"'d' must be null or an int ≥ 1, got {d!r}"
    groups = obj.get("groups", "factors")
    if not (isinstance(groups, str) and groups.strip()) and not (
            isinstance(groups, list) and groups and all(_strings(g) for g in groups)):
        return f"'groups' must be a spec such as 'factors' or a list of block-name lists, got {groups!r}"
    info = obj.get("info", {})
    rng = info.get("range") if isinstance(info, dict) else None
    if not isinstance(info, dict) or not (rng is None or isinstance(rng, dict) and isinstance(rng.get("over", {}), dict)
                                          and all(isinstance(v, list) for v in rng.get("over", {}).values())):
        return "'info' must be an object (its 'range', if any, with 'over': {parameter: [values]})"
    why = _learn_options(obj.get("learn_options", {}))
    if why:
        return why
    templates = obj.get("templates", [])
    if not isinstance(templates, list):
        return "'templates' must be a list"
    pairs = {(p["factor_type"], p["identity"]) for p in obj["pairs"]}
    for i, t in enumerate(templates):
        why = _template(t, i)
        if why:
            return why
        extra = [ident for ident in t["identities"] if (t["factor_type"], ident) not in pairs]
        if extra:
            return (f"template {i} ({t['factor_type']}) holds identity {extra[0]!r}, which 'pairs' does not list "
                    f"(a set applies its templates: list the pair or remove the template)")
    fallback = obj.get("fallback", {})
    if not isinstance(fallback, dict) or not all(isinstance(k, str) and isinstance(v, str)
                                                 for k, v in fallback.items()):
        return "'fallback' must map factor types to text"
    return ""


def check_set_file(path: str | Path, option: str = "--set") -> dict[str, Any]:
    """The JSON object of a saved constraint set (``discover --out``), checked as the module docstring says."""
    from .discovery.discovered import FORMAT, FORMAT_V1

    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"{option} {path}: no such file")
    try:
        obj = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ParameterError(f"{option} {path}: not a readable JSON file ({e})") from None
    if not isinstance(obj, dict):
        raise ParameterError(f"{option} {path}: a constraint-set file holds a JSON object, not {type(obj).__name__}")
    if obj.get("format") not in (FORMAT, FORMAT_V1):
        raise ParameterError(f"{option} {path}: not a constraint-set file (format {obj.get('format')!r}, "
                             f"expected {FORMAT!r})")
    missing = [k for k in ("problem", "pairs") if k not in obj]
    if missing:
        raise ParameterError(f"{option} {path}: lacks {' and '.join(repr(k) for k in missing)}")
    if not isinstance(obj["problem"], str):
        raise ParameterError(f"{option} {path}: 'problem' must be a problem name")
    pairs = obj["pairs"]
    if not isinstance(pairs, list) or not all(isinstance(x, dict) and isinstance(x.get("factor_type"), str)
                                              and isinstance(x.get("identity"), str) for x in pairs):
        raise ParameterError(f"{option} {path}: 'pairs' must be a list of {{factor_type, identity}} objects")
    opts = obj.get("learn_options", {})
    if not isinstance(opts, dict):
        raise ParameterError(f"{option} {path}: 'learn_options' must be an object")
    if not isinstance(obj.get("params", {}), dict):
        raise ParameterError(f"{option} {path}: 'params' must be an object")
    why = check_fields(obj)
    if why:
        raise ParameterError(f"{option} {path}: {why}")
    return obj
