"""``autotight discover PROBLEM``: progress, the comparison table, JSON output."""

from __future__ import annotations

import argparse
from contextlib import contextmanager
import json
from typing import Callable, Iterator

from ..cli import add_accept_arg, add_solver_args, solver_config
from ..cli_checks import nonneg_float, nonneg_int, pos_float
from ..io import jsonable
from ..limits import check_count, check_size
from ..outpaths import check_file, writing
from ..pretty import polynomial
from ..unbounded import compress
from ..problem import load, parse_assignments
from .carry import carry_plan
from .learn import LearnOptions
from .pipeline import DiscoveryResult, discover, n_training


def register(sub: argparse._SubParsersAction, add_problem_args: Callable) -> None:
    p = sub.add_parser("discover", help="learn, tighten and reduce redundant constraints; compare with the paper")
    add_problem_args(p)
    p.add_argument("--out", default=None, help="save the discovered set as JSON to this file (checked before the work)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--groups", default=None, help="the problem's DEFAULT_GROUPS or 'factors' (default), 'whole', "
                   "'adjacent:TYPE+TYPE' (unions of neighbouring factors), comma-joined, or explicit blocks 'a,b;c,d'")
    p.add_argument("--heldout", type=nonneg_int, default=10,
                   help="held-out instances for the sufficiency check (default 10)")
    p.add_argument("--min-gap", type=pos_float, default=6.0,
                   help="spectral gap in decades that decides the rank (default 6)")
    p.add_argument("--gap-tol", type=nonneg_float, default=1e-5,
                   help="relative cost gap counted as tight (default 1e-5)")
    add_accept_arg(p)
    p.add_argument("--no-carry", action="store_true",
                   help="select the set at -p alone, even where the problem module declares where a selection carries "
                        "to any size (CARRY; e.g. discrete_trajectory: K ≥ 20 over the noise range)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--latex", default=None, metavar="FILE",
                   help="write the discovered families' closed forms beside the paper's as LaTeX to FILE")
    add_solver_args(p, default=None, note="the carried discovery of a problem whose CARRY names a solver: that one")
    from .range import add_range_args  # discovery over a range: --sigmas, --range, --train, --train-param

    add_range_args(p)
    p.set_defaults(func=cmd_discover)


def _groups(spec: str | None):
    if spec is None:
        return None
    if ";" not in spec and all(p.strip() in ("factors", "whole") or p.strip().startswith("adjacent:")
                               for p in spec.split(",")):
        return spec
    return [tuple(x.strip() for x in g.split(",") if x.strip()) for g in spec.split(";") if g.strip()]


@contextmanager
def progress_bar(args: argparse.Namespace) -> Iterator[Callable[[str, str], None]]:
    """A progress callback ``progress(stage, text)`` drawing a bar unless --json or --no-progress."""
    bar = None
    if not args.json and not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(desc="discover", unit="step", leave=False)

    def progress(stage: str, text: str) -> None:
        if bar is not None:
            bar.set_description(f"{stage} {text}"[:60])
            bar.update(1)

    try:
        yield progress
    finally:
        if bar is not None:
            bar.close()


def cmd_discover(args: argparse.Namespace) -> int:
    from ..tightness import Criteria

    config = solver_config(args)
    if args.out is not None:
        check_file(args.out, force=args.force)
    if args.latex is not None:
        check_file(args.latex, force=args.force)
    prob = load(args.problem)
    ranged = bool(args.sigmas is not None or args.range or args.train_param or args.learn_param or args.validate
                  or args.validate_param)
    plan = None if ranged or args.no_carry else carry_plan(prob, parse_assignments(args.param))
    n_train = n_training(prob, args.train, ranged or plan is not None)
    if ranged or plan is not None or n_train > 1:
        from .range import cmd_discover_range

        if plan is not None and plan.solver:
            config = solver_config(args, default_backend=plan.solver)
        return cmd_discover_range(args, _groups(args.groups), n_train, config, plan)
    params = prob.parse_params(parse_assignments(args.param))
    check_size(prob, params)
    check_count(prob, params, f"--heldout {args.heldout}", args.heldout, per_item=3, what="held-out instances")
    with progress_bar(args) as progress:
        res = discover(prob, params, args.seed, groups=_groups(args.groups),
                       learn_options=LearnOptions(min_gap_decades=args.min_gap),
                       criteria=Criteria(gap_tol=args.gap_tol, accept=args.accept), n_heldout=args.heldout,
                       progress=progress, solver=config)
    if args.out:
        with writing(args.out):
            res.save(args.out)
    if args.json:
        print(json.dumps(jsonable(res.summary()), ensure_ascii=False))
    else:
        print(table(res))
        if args.out:
            print(f"\nsaved to {args.out}")
    from ..closed_form.cli import closed_form_output

    closed_form_output(prob, res.discovered, args)
    return 0


def _num(x) -> str:
    return "—" if x is None else f"{x:.1e}"


def _frac(h) -> str:
    return f"{h.fraction:.0%} of {len(h.seeds)}" if h is not None and h.seeds else "—"


def _primary_frac(h) -> str:
    return f"{h.primary_fraction:.0%} of {len(h.seeds)}" if h is not None and h.primary_tight else ""


def table(res: DiscoveryResult) -> str:
    """The comparison with the paper, and the discovered constraints grouped by factor."""
    s = res.summary()
    lines = [f"problem {res.problem}  params {res.params}  seed {res.seed}",
             f"learned per group: {len(res.catalog.groups)} groups, {s['n_candidates']} new candidates in "
             f"{s['n_candidate_pairs']} (factor type, identity) pairs, {s['n_rejected_heldout']} rejected on held-out "
             "samples",
             f"smallest spectral gap: {min(s['spectral_gaps'].values()):.1f} decades",
             f"result: {'TIGHT' if res.tight else 'NOT TIGHT'} ({res.accept}) — {res.explanation()}",
             f"log SVR {res.final_log_svr:.2f} (primary alone {s['log_svr_primary']:.2f}); final relative cost gap "
             f"{_num(s['final_rel_gap'])}, status {s['final_status']}; {res.n_solves} SDP solver calls "
             f"({res.times.get('sdp_s', 0.0):.1f} s)",
             *([f"primary constraints alone: unbounded in {compress(res.tightened.primary_unbounded)}"]
               if res.tightened.primary_unbounded else []),
             *([f"ignored spectral gaps below roundoff in {len(s['spectral_gaps_ignored'])} group(s) "
                f"(largest {max(g['decades'] for g in s['spectral_gaps_ignored'].values()):.1f} decades)"]
               if s['spectral_gaps_ignored'] else []), "",
             f"{'set':<28}{'constraints':>12}{'in learned span':>18}{'tight (learn inst.)':>21}"
             f"{'tight (held-out)':>18}",
             f"{'primary':<28}{s['n_primary']:>12}{'yes':>18}{str(res.tightened.primary_verdict.tight):>21}"
             f"{_primary_frac(res.heldout):>18}"]
    for fam, info in res.paper_span.items():
        r = info["max_residual"]
        span = f"{'yes' if r < 1e-8 else 'NO'} ({r:.0e})"
        lines.append(f"{'paper ' + fam:<28}{info['count']:>12}{span:>18}")
    if res.paper_tight is not None:
        ph = res.paper_heldout
        lines.append(f"{'paper (all families)':<28}{s['n_paper']:>12}{'':>18}{str(res.paper_tight):>21}"
                     f"{_frac(ph):>18}")
    like = sorted(set(res.resembles.values()))
    label = "discovered (irreducible)" if s["irreducible"] else "discovered" if s["minimal_is_reduced"] \
        else "greedy (NOT reduced)"
    lines.append(f"{label:<28}"
                 f"{s['n_minimal']:>12}{'':>18}{str(res.tight):>21}"
                 f"{_frac(res.heldout):>18}")
    lines.append(f"  {len(res.discovered.pairs)} pairs; resembles: {', '.join(like) or '—'}")
    lines.append("")
    by_factor: dict[str, list] = {}
    for c in res.constraints:
        by_factor.setdefault(c.factor or "", []).append(c)
    for f, cons in by_factor.items():
        lines.append(f"[{f}]")
        for c in cons:
            like = res.resembles.get(c.name, "?")
            lines.append(f"  ({c.identity}, like {like})  {polynomial(c.A, res.model.variables)}")
    return "\n".join(lines)
