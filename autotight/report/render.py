"""The readable report: summary tables, ``report.md`` and a self-contained ``report.html``."""

from __future__ import annotations

import base64
import html
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from ..io import atomic_write_text
from ..outpaths import writing
from . import figures
from .table import Table
from .store import load_trials, solved_rows

CAPTIONS = {
    "trapped": "Fraction of local solves from a random start that end above the global cost "
               "(the lowest local cost, or the SDP cost where the relaxation is tight); bars: 95 % Wilson interval.",
    "log_svr": "log SVR of the SDP solution per constraint set; above the dashed line counts as rank d "
               "(d = lifting width, 1 for a vector lifting).",
    "tight": "Fraction of SDP solves judged tight (rank d, and the bracket [dual cost, best feasible cost] "
             "within the gap tolerance).",
    "times": "Median solve times of the SDP per constraint set and of the local solver.",
}


@dataclass
class Summary:
    """What the report shows: facts about the sweep, tables, figures."""

    title: str
    facts: list[tuple[str, str]]
    tables: list[Table]
    figures: dict[str, Path] = field(default_factory=dict)
    captions: dict[str, str] = field(default_factory=lambda: dict(CAPTIONS))


def _sig(s: float) -> str:
    return f"{s:.3g}"


def _frac(v: pd.Series) -> str:
    return f"{v.mean():.2f}" if len(v) else "–"


def _median(v: pd.Series, fmt: str = ".3g") -> str:
    x = v.to_numpy(float)
    x = x[~np.isnan(x)]
    return format(np.median(x), fmt) if x.size else "–"


VERDICT_RULE = (
    "How a verdict is decided (autotight/tightness.py). The SDP gives its dual cost D (a lower bound on the "
    "optimum, up to the accuracy the solver reached on that solve) and its primal cost P; the best feasible "
    "cost U is the lowest of the local solves (from the ground truth and a random start) and of one local "
    "solve started at the SDP's own estimate. The accuracy acc of a solve is read off its residuals "
    "(|P − D|, the constraint residuals weighted by the multipliers, and λ_min of the dual slack times a "
    "trace bound). Cost-tight: U − D ≤ gap_tol·|U| + cost_atol·‖Q‖_max·tr X (+ acc); not tight: "
    "U − P exceeds that by more than acc; otherwise undecided, and the SDP is solved once more at a 100× "
    "tighter tolerance. Rank-tight: log SVR = log10(λ_d/λ_{d+1}) > the threshold. Tight = rank-tight and "
    "cost-tight; undecided verdicts are never counted as not tight. Certified: the SDP's multipliers y "
    "prove the best feasible point optimal to gap_tol (autotight/certificate.py). Trapped: the random-start "
    "local solve ends above the best feasible cost.")


def _verdicts(at: pd.DataFrame, s: str) -> list[str]:
    """Fractions of one set's solves: rank-tight, cost-tight, certified, undecided, and the SDP's estimate
    beating every local search."""
    x = at[at["constraint_set"] == s]
    cols = ("rank_tight", "cost_tight", "certified", "undecided", "sdp_beats_local")
    return [_frac(x[c].astype(float)) if c in x else "–" for c in cols]


def _count(n: np.ndarray) -> str:
    return "–" if not n.size else f"{int(np.median(n))}" if n.min() == n.max() \
        else f"{int(np.median(n))} (range {int(n.min())}–{int(n.max())})"


RANK_TIGHT_CAPTION = ("Tight: log SVR = log10(λ_d/λ_{d+1}) above the rank-d threshold and the cost bracket "
                      "closed (see 'Verdicts per noise level' for how a verdict is decided).")


def tight_rule(crit: dict[str, Any]) -> tuple[str, str, str]:
    """(the header's "Tight" fact, the fraction table's caption, the tight figure's caption) for the
    sweep's criteria."""
    accept = crit.get("accept", "rank")
    if accept == "cost":
        return (f"the cost bracket within {crit['gap_tol']:g} relative and a dual certificate of the best feasible "
                "point; the rank is not required (accept: cost; see 'Verdicts per noise level')",
                "Tight (accept: cost): the cost bracket closed and the best feasible point certified by the SDP's "
                "multipliers; the rank is not required (see 'Verdicts per noise level').",
                "Fraction of SDP solves judged tight (accept: cost: the bracket [dual cost, best feasible cost] "
                "within the gap tolerance and the best feasible point certified; the rank is not required).")
    if accept == "certified":
        return ("a dual certificate of the best feasible point (accept: certified; see 'Verdicts per noise level')",
                "Tight (accept: certified): the best feasible point certified by the SDP's multipliers.",
                "Fraction of SDP solves whose multipliers certify the best feasible point (accept: certified).")
    return (f"log SVR > {crit['min_log_svr']:g} and the cost bracket within {crit['gap_tol']:g} relative "
            f"(accept: {accept}; see 'Verdicts per noise level')",
            RANK_TIGHT_CAPTION, CAPTIONS["tight"])


def tables(df: pd.DataFrame, sigmas: Sequence[float], sets: Sequence[str],
           structure: SetStructure | None = None, tight_caption: str | None = None) -> list[Table]:
    """Constraint counts (with each set's pairs or families and its constraints beyond the primary
    ones when ``structure`` is given), fraction tight (``tight_caption``: ``tight_rule``'s, rank by
    default), median log SVR, median times, solver statuses."""
    ok = df[solved_rows(df)]
    per_trial = ok.drop_duplicates(["sigma_index", "trial"])
    counts = []
    for s in sets:
        n = ok[ok["constraint_set"] == s]["n_constraints"].to_numpy(float)
        row = [s, _count(n)]
        if structure is not None:
            row += [_count(n - structure.n_primary) if n.size else "–", structure.parts.get(s, "–")]
        counts.append(row)
    head = ["set", "constraints"] + (["beyond h² and primary", "made of"] if structure is not None else [])
    out = [Table("Constraints per set", head, counts,
                 "Counts include the homogenisation and primary constraints"
                 + (f" ({structure.n_primary} on the report's instances); 'made of' gives a learned set's "
                    "(factor type, identity) pairs, each instantiated on every factor of its type, and the "
                    "paper's families." if structure is not None else "."))]
    rows_t, rows_s, rows_time = [], [], []
    for i, sg in enumerate(sigmas):
        at = df[df["sigma_index"] == i]
        trials = at.drop_duplicates("trial")
        rows_t.append([_sig(sg), str(len(trials))]
                      + [_frac(at[at["constraint_set"] == s]["tight"]) for s in sets]
                      + [_frac(per_trial[per_trial["sigma_index"] == i]["trapped"])])
        rows_s.append([_sig(sg)] + [_median(at[at["constraint_set"] == s]["log_svr"], ".1f") for s in sets])
        pt = per_trial[per_trial["sigma_index"] == i]
        rows_time.append([_sig(sg)] + [_median(at[at["constraint_set"] == s]["sdp_time_s"]) for s in sets]
                         + [_median(pt["local_truth_time_s"]), _median(pt["local_random_time_s"])])
    out.append(Table("Fraction tight per noise level", ["σ", "trials", *[f"tight: {s}" for s in sets],
                                                        "trapped (random start)"], rows_t,
                     tight_caption or RANK_TIGHT_CAPTION))
    rows_v = []
    for i, sg in enumerate(sigmas):
        at = ok[ok["sigma_index"] == i]
        for s in sets:
            rows_v.append([_sig(sg), s, *_verdicts(at, s)])
    out.append(Table("Verdicts per noise level", ["σ", "set", "rank-tight", "cost-tight", "certified", "undecided",
                                                   "SDP estimate beats local search"], rows_v, VERDICT_RULE))
    marginal = _has_marginal(df)
    if marginal:  # the module's reduced X (continuous time: the marginalised X, as the paper plots it)
        for i, row in enumerate(rows_s):
            at = df[df["sigma_index"] == i]
            row += [_median(at[at["constraint_set"] == s]["log_svr_marginal"], ".1f") for s in sets]
    out.append(Table("Median log SVR", ["σ", *sets, *[f"{s} (marginalised X)" for s in sets if marginal]], rows_s,
                     "Marginalised X: log SVR of the X with ϖ removed by the Schur complement, as the paper's "
                     "figure plots it, whichever formulation was solved (the module's marginal_log_svr)."
                     if marginal else ""))
    brackets = bracket_table(df, sigmas, sets)
    if brackets is not None:
        out.append(brackets)
    out.append(Table("Median times (s)", ["σ", *[f"SDP {s}" for s in sets], "local (truth)", "local (random)"],
                     rows_time))
    status = df.groupby("constraint_set")["status"].value_counts().unstack(fill_value=0)
    if set(status.columns) != {"Solved"}:
        cols = list(status.columns)
        out.append(Table("Solver statuses", ["set", *cols],
                         [[s, *[str(int(status.loc[s, c])) for c in cols]] for s in sets if s in status.index]))
    return out


#: relative excess over U below which P > U or D > U is roundoff of summing the cost, not a solver error
ROUNDOFF_RTOL = 1e-9

BRACKET_NOTE = (
    "Each solve's interval against the best feasible cost U (differences relative to |U|, or to tol where that "
    "is larger: a zero cost). P is the solver's primal cost. D = bᵀy is the dual cost of the solver's "
    "multipliers y or of their polish onto H(y)x̂ = 0 at the best feasible point x̂ (the least change of y), "
    "the polish kept when its L is larger, or when the solver's D exceeds f(x̂) and the polish is no less dual "
    "feasible, never when it would raise D above both the solver's D and f(x̂); an excess over f(x̂) that is "
    "left is taken off the multiplier of h² = 1, which only adds a PSD term to H (autotight/dual_polish.py). "
    "A D above U shows that y is slightly infeasible, so D alone is not a bound. L = D − max(−λ_min(H), 0)·tr X "
    "(H = Q − Σ yᵢAᵢ) is the lower end the verdict uses: the dual cost corrected for that infeasibility; where "
    "that leaves the verdict undecided, the correction is also taken in the solve's scaled frame X = D′X′D′, "
    "max(−λ_min(D′HD′), 0)·tr(D′⁻¹XD′⁻¹), and the smaller one is used. "
    "'P and D above U' counts solves whose "
    "P and D both exceed U by more than 1e-9 relative (roundoff), 'above U beyond acc' those where both exceed U "
    "by more than the solve's own accuracy acc (a solve that had not converged); 'solver's D above U' counts "
    "solves whose solver's own dual cost (sdp_dual_raw where the polish was kept) exceeds U beyond roundoff; "
    "'L above U' counts solves whose corrected interval [L, P] misses U beyond roundoff (one whose L exceeds U "
    "by more than the tolerance and its accuracy is judged undecided: the solve is wrong). acc: the accuracy of "
    "the solve and tol the gap the verdict allows, gap_tol·|U| + cost_atol·‖Q‖_max·tr X (see 'Verdicts per "
    "noise level'); where tol is not small against |U| (the cost_atol term: a cost far below the scale of its "
    "own terms), the bracket cannot separate a tight from a loose relaxation by much less than tol, and the "
    "verdict rests on the rank test.")


def bracket_table(df: pd.DataFrame, sigmas: Sequence[float], sets: Sequence[str]) -> Table | None:
    """Per σ and set: solves whose P and D both exceed U, those whose solver's own dual cost does
    (trials saved with ``sdp_dual_raw``), solves whose corrected bracket [L, P] misses U, the largest
    excess and the medians of U − L, acc and tol, all relative to max(|U|, tol); None for trials saved
    without L."""
    if "sdp_lower_bound" not in df.columns or not df["sdp_lower_bound"].notna().any():
        return None
    ok = df[solved_rows(df) & df["sdp_lower_bound"].notna()]
    has_raw = "sdp_dual_raw" in ok.columns and ok["sdp_dual_raw"].notna().any()
    rows = []
    for i, sg in enumerate(sigmas):
        for s in sets:
            x = ok[(ok["sigma_index"] == i) & (ok["constraint_set"] == s)]
            if x.empty:
                continue
            U = x["upper_bound"].to_numpy(float)
            scale = np.maximum(np.abs(U), x["sdp_tolerance"].to_numpy(float))  # a zero cost: its absolute tolerance
            raw = (np.minimum(x["sdp_cost"], x["sdp_dual_cost"]).to_numpy(float) - U) / scale
            low = (x["sdp_lower_bound"].to_numpy(float) - U) / scale
            acc = x["sdp_accuracy"].to_numpy(float) / scale
            solver_d = []
            if has_raw:
                own = x["sdp_dual_raw"].fillna(x["sdp_dual_cost"]).to_numpy(float)
                solver_d = [str(int(np.sum((own - U) / scale > ROUNDOFF_RTOL)))]
            rows.append([_sig(sg), s, str(len(x)), str(int(np.sum(raw > ROUNDOFF_RTOL))), f"{np.nanmax(raw):.1e}",
                         str(int(np.sum(raw > np.maximum(acc, ROUNDOFF_RTOL)))), *solver_d,
                         str(int(np.sum(low > ROUNDOFF_RTOL))), f"{np.nanmedian(-low):.1e}",
                         f"{np.nanmedian(acc):.1e}", f"{np.nanmedian(x['sdp_tolerance'].to_numpy(float) / scale):.1e}"])
    return Table("Bracket against the best feasible cost",
                 ["σ", "set", "solves", "P and D above U", "max excess min(P, D) − U", "above U beyond acc",
                  *(["solver's D above U"] if has_raw else []), "L above U", "median U − L", "median acc",
                  "median tol"], rows, BRACKET_NOTE)


def _has_marginal(df: pd.DataFrame) -> bool:
    """Whether the trials hold log SVR on the module's reduced X (``log_svr_marginal``)."""
    return "log_svr_marginal" in df.columns and bool(df["log_svr_marginal"].notna().any())


def paper_table(df: pd.DataFrame, sigmas: Sequence[float], claim: dict[str, Any]) -> Table | None:
    """"Against the paper": per σ, our fraction tight, median log SVR (on the marginalised X where the
    module reports it) and trapped fraction for the paper's set, beside what the paper reports
    (a module's ``META.paper_claim``: source, set, by_sigma {σ: text}, default text)."""
    name = claim.get("set", "paper")
    at_set = df[df["constraint_set"] == name]
    if at_set.empty:
        return None
    col = "log_svr_marginal" if _has_marginal(df) else "log_svr"
    by_sigma = {float(k): v for k, v in claim.get("by_sigma", {}).items()}
    rows = []
    for i, sg in enumerate(sigmas):
        at = at_set[at_set["sigma_index"] == i]
        said = next((v for k, v in by_sigma.items() if np.isclose(k, sg, rtol=1e-2)), claim.get("default", "–"))
        rows.append([_sig(sg), _frac(at["tight"]), _median(at[col], ".1f"), _frac(at["trapped"]), said])
    what = "marginalised X" if col == "log_svr_marginal" else "X"
    return Table("Against the paper", ["σ", f"tight: {name}", f"median log SVR ({what})", "trapped", "the paper"],
                 rows, f"Our verdicts for the set '{name}' beside what the paper reports ({claim.get('source', '')}).")


def _claim(meta: dict[str, Any]) -> dict[str, Any] | None:
    """The problem module's ``META.paper_claim``, or None (no such attribute, or the module no longer loads)."""
    from ..errors import AutotightError
    from ..module_parts import paper_claim
    from ..problem import load

    try:
        return paper_claim(load(meta.get("source") or meta["problem"]))
    except AutotightError:
        return None


@dataclass
class SetStructure:
    """n_primary: homogenisation and primary constraints of the report's instances; parts: per set, the
    pairs of a learned set or the paper's families, as text."""

    n_primary: int
    parts: dict[str, str]


def _pairs(path: Path, sha256: str | None = None) -> str | None:
    """"n pairs" of a saved set, or None when it cannot be read (or its hash differs from the sweep's)."""
    import json

    from .sweep import _sha256

    try:
        if sha256 is not None and _sha256(path) != sha256:
            return None
        n = len(json.loads(path.read_bytes())["pairs"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return f"{n} pair{'s' if n != 1 else ''}"


def set_structure(out: Path, meta: dict[str, Any]) -> SetStructure | None:
    """The sets' structure at the report's parameters (seed 0), or None when the problem cannot be
    built here.  A ``file:`` set is read from the path in the recorded command (relative to the
    working directory), and only when its hash is the sweep's."""
    import shlex

    from ..errors import AutotightError
    from ..problem import load
    from .spec import file_sets
    from .sweep import DISCOVERED_NAME

    try:
        problem = load(meta.get("source") or meta["problem"])
        model = problem.build(problem.generate(problem.parse_params(dict(meta["params"])), 0))
    except AutotightError:
        return None
    parts = {"paper": f"{len(model.paper)} families ({', '.join(model.paper)})" if model.paper else "–"}
    disc = _pairs(Path(out) / DISCOVERED_NAME)
    if disc:
        parts["discovered"] = disc
    command = meta["runs"][-1].get("command", "") if meta.get("runs") else ""
    try:
        words = shlex.split(command)
    except ValueError:  # a hand-edited command with unbalanced quotes: no file sets
        words = []
    sets_arg = next((a.split("=", 1)[-1] for a in words if a.startswith("--sets=")), None)
    if sets_arg is None and "--sets" in words[:-1]:
        sets_arg = words[words.index("--sets") + 1]
    for name, path in (file_sets(sets_arg)[1] if sets_arg else ()):
        got = _pairs(Path(path), meta.get("files", {}).get(name, {}).get("sha256"))
        if got:
            parts[name] = got
    return SetStructure(len(model.primary()), parts)


def summarize(out: Path, meta: dict[str, Any]) -> Summary:
    """Read the results in ``out`` and draw the figures."""
    df = load_trials(out, meta["trials"])
    sigmas, sets = meta["sigmas"], meta["sets"]
    crit = meta["criteria"]
    done = df.drop_duplicates(["sigma_index", "trial"]).shape[0]
    rule = tight_rule(crit)
    facts = [("Problem", f"{meta['problem']} — {meta.get('description', '')}".rstrip(" —")),
             ("Parameters", ", ".join(f"{k} = {v}" for k, v in meta["params"].items()) or "defaults"),
             ("Noise levels σ", ", ".join(_sig(s) for s in sigmas)),
             ("Trials", f"{done} of {meta['trials'] * len(sigmas)} done ({meta['trials']} per σ)"),
             ("Constraint sets", ", ".join(sets)),
             ("Base seed", f"{meta['seed']} (trial seeds: SeedSequence((seed, σ index, trial)))"),
             ("Tight", rule[0]),
             ("Trapped", f"random-start local cost above the global cost by more than {meta['trap_rtol']:g} "
                         "relative"),
             ("Command", meta["runs"][-1].get("command", "") if meta.get("runs") else ""),
             ("Versions", ", ".join(f"{k} {v}" for k, v in meta.get("versions", {}).items())),
             ("Generated", time.strftime("%Y-%m-%d %H:%M"))]
    figs = figures.make_all(df, sigmas, sets, out, trap_rtol=meta["trap_rtol"], rank_line=crit["min_log_svr"]) \
        if len(df) else {}
    tabs = tables(df, sigmas, sets, set_structure(out, meta), rule[1])
    claim = _claim(meta)
    versus = paper_table(df, sigmas, claim) if claim and len(df) else None
    if versus is not None:
        tabs.insert(1, versus)
    from .closed_forms import closed_form_tables

    tabs += closed_form_tables(out, meta)
    return Summary(f"Tightness report: {meta['problem']}", facts, tabs, figs,
                   CAPTIONS | {"tight": rule[2]})


def markdown(s: Summary) -> str:
    lines = [f"# {s.title}", ""]
    lines += [f"- **{k}**: {v}" if k != "Command" else f"- **{k}**: `{v}`" for k, v in s.facts]
    for t in s.tables:
        lines += ["", f"## {t.title}", ""]
        if t.note:
            lines += [t.note, ""]
        lines += ["| " + " | ".join(t.header) + " |", "|" + "---|" * len(t.header)]
        lines += ["| " + " | ".join(r) + " |" for r in t.rows]
    if s.figures:
        lines += ["", "## Figures", ""]
        for name, path in s.figures.items():
            lines += [f"![{name}]({path.name})", "", s.captions.get(name, ""), ""]
    return "\n".join(lines).rstrip() + "\n"


STYLE = ("body{font-family:system-ui,sans-serif;max-width:60rem;margin:2rem auto;padding:0 1rem;color:#222}"
         "table{border-collapse:collapse;margin:.5rem 0 1rem}th,td{border:1px solid #ccc;padding:.25rem .6rem;"
         "text-align:right}th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}"
         "figure{margin:1rem 0}img{max-width:100%}figcaption{font-size:.9rem;color:#555}"
         "code{background:#f4f4f4;padding:0 .2rem}dt{font-weight:600}dd{margin:0 0 .4rem 1rem}")


def html_page(s: Summary) -> str:
    e = html.escape
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>{e(s.title)}</title>", f"<style>{STYLE}</style>", "</head>", "<body>", f"<h1>{e(s.title)}</h1>",
             "<dl>"]
    for k, v in s.facts:
        parts.append(f"<dt>{e(k)}</dt><dd>{f'<code>{e(v)}</code>' if k == 'Command' else e(v)}</dd>")
    parts.append("</dl>")
    for t in s.tables:
        parts.append(f"<h2>{e(t.title)}</h2>")
        if t.note:
            parts.append(f"<p>{e(t.note)}</p>")
        parts.append("<table><thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in t.header) + "</tr></thead><tbody>")
        parts += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in r) + "</tr>" for r in t.rows]
        parts.append("</tbody></table>")
    if s.figures:
        parts.append("<h2>Figures</h2>")
    for name, path in s.figures.items():
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        parts.append(f'<figure><img alt="{e(name)}" src="data:image/png;base64,{data}">'
                     f"<figcaption>{e(s.captions.get(name, name))}</figcaption></figure>")
    parts += ["</body>", "</html>", ""]
    return "\n".join(parts)


def render(out: str | Path, meta: dict[str, Any]) -> dict[str, Path]:
    """Figures, ``report.md`` and ``report.html`` in ``out``; returns every file written."""
    out = Path(out)
    s = summarize(out, meta)
    md, page = out / "report.md", out / "report.html"
    for path, text in ((md, markdown(s)), (page, html_page(s))):
        with writing(path):
            atomic_write_text(path, text)
    return {**s.figures, "report.md": md, "report.html": page}
