"""``autotight templates SET.json --out NEW.json``: learn a saved set's templates again.

For a set saved before a factor type could have a template (e.g. before transport templates: the type
is listed under ``fallback`` and re-learned per factor on every instance).  The pairs, parameters, seed
and learning options stay; the templates are learned from them as ``discover --out`` learns them, and
the learning instance's records are copied unchanged.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from ..outpaths import check_file, writing
from ..problem import load
from ..discovery.discovered import DiscoveredSet
from ..discovery.templates import TypeTemplate

#: records of the learning instance that are copied from the old file
KEPT = ("variables", "d", "constraints_by_factor", "learning_instance", "summary")


def register(sub: argparse._SubParsersAction, add_problem_args=None) -> None:
    """The ``templates`` subcommand (``add_problem_args`` unused: the set file names its problem)."""
    p = sub.add_parser("templates", help="learn a saved constraint set's templates again (e.g. for factor types "
                                         "listed under 'fallback')")
    p.add_argument("set", help="a constraint-set file (from `discover --out`)")
    p.add_argument("--out", required=True, help="the new file (checked before the work)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.set_defaults(func=cmd_templates)


def cmd_templates(args: argparse.Namespace) -> int:
    check_file(args.out, force=args.force)
    ds = DiscoveredSet.load(args.set)
    prob = load(ds.problem)
    old = json.loads(Path(args.set).read_text(encoding="utf-8"))
    before = {} if ds.templates is None else dict(ds.templates.fallback)
    ds.templates = None
    ts = ds.template_set(prob)
    extra = {k: old[k] for k in KEPT if k in old} | {"templates_relearned_from": str(args.set)}
    with writing(args.out), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a diversion is the note below
        written = ds.save(args.out, extra=extra, problem=prob, replace=args.force)
    if Path(written) != Path(args.out):
        print(f"autotight: note: {args.out} appeared meanwhile and is kept; the set is saved as {written}",
              file=sys.stderr)
    for t, tpl in sorted(ts.templates.items()):
        how = f"polynomial of degree {tpl.degree}" if isinstance(tpl, TypeTemplate) else "transport"
        was = " (was re-learned per factor)" if t in before else ""
        print(f"{t}: {len(tpl.identities)} identities, {how}{was}; re-learning error "
              f"{tpl.check.get('relearn_rel_error', float('nan')):.1e}")
    for t, why in sorted(ts.fallback.items()):
        print(f"{t}: no template: {why}")
    print(f"saved to {args.out}")
    return 0
