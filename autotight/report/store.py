"""The results folder: ``meta.json`` (what the sweep is) and ``trials.csv`` (one row per trial and set).

Each finished trial is appended with one ``write`` and an fsync.  On reading, a torn last line or
a trial with missing set rows (a crash mid-write) is dropped and the file rewritten atomically,
so a trial is either fully present or absent.  A folder holding a different sweep, or files that
no report wrote, is refused before any work (``precheck``).  Every write goes through
``autotight.outpaths.writing``: a full disk is a one-line error and leaves no partial file.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

import pandas as pd

from ..io import atomic_write_text, jsonable, versions, write_json
from ..outpaths import writing
from ..sdp.result import Status
from .spec import ReportError

CSV_NAME = "trials.csv"
META_NAME = "meta.json"
#: sweep settings added after the first reports were written, with the value they had implicitly
SETTING_DEFAULTS: dict[str, Any] = {"decompose": False}
#: files a report writes besides meta.json (a folder holding one of them without meta.json is refused)
OUTPUTS = (CSV_NAME, "report.md", "report.html", "trapped.png", "log_svr.png", "tight.png", "times.png")
#: every name a report folder may hold before its meta.json exists (an interrupted first run, a discovered set)
OWN_FILES = (META_NAME, *OUTPUTS, "discovered.json", ".lock")
REPORT_TITLE = "# Tightness report"
#: the statuses a solve can end with (Clarabel's, which the IPM and the cvxpy path map to), for --redo
STATUSES = tuple(Status)
#: a trial that raised is saved with the status "Error: <exception type>: <message>" (``trial.run_trial``)
ERROR = "Error"
BOOL_COLUMNS = ("tight", "rank_tight", "cost_tight", "local_converged_truth", "local_converged_random", "trapped")


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    if hasattr(v, "item"):  # numpy scalar
        return _cell(v.item())
    return str(v).replace("\r", " ").replace("\n", " ")


def _subsequence(short: Sequence[str], long: Sequence[str]) -> bool:
    """Whether ``short`` is ``long`` with some entries left out (order kept)."""
    it = iter(long)
    return all(any(c == x for x in it) for c in short)


def _norm(obj: Any) -> Any:
    """JSON-normalised (tuples → lists, floats round-tripped) for comparing settings."""
    return json.loads(json.dumps(jsonable(obj)))


class Store:
    """``out/meta.json`` and ``out/trials.csv`` for one sweep."""

    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.csv = self.out / CSV_NAME
        self.meta_path = self.out / META_NAME
        self.columns: list[str] = []
        self.sets: list[str] = []
        self.version_changes: list[str] = []
        self.added_columns: list[str] = []
        self.dropped = 0

    # -- settings ---------------------------------------------------------------------------
    def precheck(self, identity: dict[str, Any]) -> None:
        """Refuse, before any work, a folder holding another sweep (settings in ``identity`` that
        differ; the discovered set and the columns are checked by ``open``) or files no report wrote."""
        if not self.out.is_dir():
            return
        meta = self.meta()
        md = self.out / "report.md"
        if md.is_file() and not _starts_with(md, REPORT_TITLE):
            raise ReportError(f"{md} is not a report written by autotight; use another --out or remove it")
        if meta is None:
            foreign = [n for n in OUTPUTS if (self.out / n).exists() and not (n == CSV_NAME and
                                                                              not (self.out / n).stat().st_size)]
            if foreign:
                raise ReportError(f"{self.out / foreign[0]} exists without {META_NAME}; cannot check its settings — "
                                  "use another --out or remove it")
            unrelated = sorted(p.name for p in self.out.iterdir() if p.name not in OWN_FILES
                               and not (p.name.startswith(".") and p.name.endswith(".tmp")))
            if unrelated:
                raise ReportError(f"{self.out} holds files no report wrote ({', '.join(unrelated[:3])}"
                                  f"{', …' if len(unrelated) > 3 else ''}); use an empty or new folder for --out")
            return
        self._compare(meta, _norm(identity))

    def _compare(self, meta: dict[str, Any], ident: dict[str, Any]) -> None:
        meta = {**SETTING_DEFAULTS, **meta}  # settings added later default for folders written before them
        diff = [k for k in ident if _norm(meta.get(k)) != ident[k]]
        if diff:
            k = diff[0]
            raise ReportError(f"{self.out} holds a different sweep ({k}: {_short(meta.get(k))} there, "
                              f"{_short(ident[k])} here; {len(diff)} setting(s) differ: {', '.join(diff)}) — "
                              "use another --out or remove that folder")

    def open(self, identity: dict[str, Any], columns: Sequence[str], sets: Sequence[str], trials: int,
             info: dict[str, Any] | None = None, run_info: dict[str, Any] | None = None,
             redo: Sequence[str] = ()) -> set[tuple[int, int]]:
        """Create or check the folder; returns the (σ index, trial) keys already done.

        ``identity`` must match a previous run's; ``info`` (e.g. a description) is stored, not compared;
        ``run_info`` is appended to the list of runs.  Trials with a row whose status is in ``redo``
        are removed from the CSV (their count is ``self.dropped``), so they are computed again.
        """
        self.columns, self.sets = list(columns), list(sets)
        ident = _norm(dict(identity, columns=list(columns)))
        meta = self.meta()
        if meta is None:
            if self.csv.exists() and self.csv.stat().st_size:
                raise ReportError(f"{self.csv} exists without {META_NAME}; cannot check its settings — "
                                  "use another --out or remove it")
            meta = {"format": 1, **ident, "created": time.strftime("%Y-%m-%dT%H:%M:%S"), "runs": []}
            self._write_meta(meta)  # first: a folder with meta.json and no CSV resumes; the reverse is refused
        else:
            self._compare(meta, {k: v for k, v in ident.items() if k != "columns"})  # another sweep: untouched
            self.added_columns = self._add_columns(meta)
            if self.added_columns:
                run_info = dict(run_info or {}, added_columns=self.added_columns)
            self._compare(meta, ident)
        rows = self._load_rows()
        self.dropped = 0
        if redo:
            ist, ii, it = (self.columns.index(c) for c in ("status", "sigma_index", "trial"))
            again = self._keys(r for r in rows if redo_matches(r[ist], redo))
            if again:
                rows = [r for r in rows if (int(r[ii]), int(r[it])) not in again]
                self._rewrite(rows)
                self.dropped = len(again)
                run_info = dict(run_info or {}, redo=list(redo), redone_trials=len(again))
        meta.update(info or {})
        meta["trials"] = int(trials)
        now = versions()
        old = meta.get("versions", now)
        self.version_changes = [f"{k} {old.get(k)} → {v}" for k, v in now.items() if old.get(k) != v]
        meta["versions"] = now
        meta["runs"] = [*meta.get("runs", []), {"started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                                                "versions": meta["versions"], **(run_info or {})}]
        self._write_meta(meta)
        return self._keys(rows)

    def _add_columns(self, meta: dict[str, Any]) -> list[str]:
        """Upgrade a folder written before ``self.columns`` gained entries: when its columns are these
        with some left out (order kept), the CSV is rewritten with the new header and empty cells for
        the trials saved before (nothing else changes), and ``meta`` records the new columns.  Returns
        the added column names ([] when there is nothing to upgrade)."""
        old = meta.get("columns")
        if not isinstance(old, list) or old == self.columns or not _subsequence(old, self.columns):
            return []
        if self.csv.exists() and self.csv.stat().st_size:
            lines = self._lines()
            if _row(lines[0]) != old:
                return []  # not what meta.json says: left to the column check
            at = [old.index(c) if c in old else -1 for c in self.columns]
            body = [r for r in (_row(ln) for ln in lines[1:] if ln) if len(r) == len(old)]
            self._rewrite([[r[i] if i >= 0 else "" for i in at] for r in body])
        meta["columns"] = list(self.columns)
        self._write_meta(meta)
        return [c for c in self.columns if c not in old]

    def _write_meta(self, meta: dict[str, Any]) -> None:
        with writing(self.meta_path):
            write_json(self.meta_path, meta)

    def meta(self) -> dict[str, Any] | None:
        if not self.meta_path.exists():
            return None
        try:
            meta = json.loads(self.meta_path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise ReportError(f"{self.meta_path} is not valid JSON ({e}); remove it or use another --out") from None
        except OSError as e:
            raise ReportError(f"cannot read {self.meta_path}: {e.strerror or e}") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("runs", []), list):
            raise ReportError(f"{self.meta_path} is not a report's settings (a JSON object); "
                              "remove it or use another --out")
        return meta

    # -- rows -------------------------------------------------------------------------------
    def _load_rows(self) -> list[list[str]]:
        """Complete trials' rows (raw strings); repairs the file if anything was dropped or duplicated."""
        header_line = ",".join(self.columns) + "\n"
        if not self.csv.exists():
            with writing(self.csv):
                atomic_write_text(self.csv, header_line)
            return []
        lines = self._lines()
        damaged = lines[-1] != ""  # a torn last line has no newline
        lines = lines[:-1]
        if not lines:
            with writing(self.csv):
                atomic_write_text(self.csv, header_line)
            return []
        header = _row(lines[0])
        if header != self.columns:
            raise ReportError(f"{self.csv} has other columns than this sweep writes; use another --out")
        parsed = [_row(ln) for ln in lines[1:]]  # a line with bad bytes parses to [] and is dropped
        good = [r for r in parsed if len(r) == len(self.columns)]
        damaged |= len(good) != len(parsed)
        kept = self._complete(good)
        if damaged or len(kept) != len(good):
            self._rewrite(kept)
        return kept

    def _lines(self) -> list[str]:
        """The CSV's lines (the last is "" when the file ends with a newline); bytes that are not UTF-8
        become U+FFFD, so the line holding them is dropped as damaged (``_row``)."""
        try:
            data = self.csv.read_bytes()
        except OSError as e:
            raise ReportError(f"cannot read {self.csv}: {e.strerror or e}") from None
        return data.decode("utf-8", errors="replace").split("\n")

    def _complete(self, rows: list[list[str]]) -> list[list[str]]:
        """Rows of trials that have exactly one row per set (first occurrence of each trial kept)."""
        iset, ii, it = (self.columns.index(c) for c in ("constraint_set", "sigma_index", "trial"))
        groups: dict[tuple[str, str], dict[str, list[str]]] = {}
        for r in rows:
            groups.setdefault((r[ii], r[it]), {}).setdefault(r[iset], r)
        out = []
        for g in groups.values():
            if sorted(g) == sorted(self.sets):
                out += [g[s] for s in self.sets]
        return out

    def _keys(self, rows: Iterable[list[str]]) -> set[tuple[int, int]]:
        ii, it = self.columns.index("sigma_index"), self.columns.index("trial")
        return {(int(r[ii]), int(r[it])) for r in rows}

    def _text(self, rows: Iterable[Sequence[Any]]) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerows(rows)
        return buf.getvalue()

    def _rewrite(self, rows: list[list[str]]) -> None:
        with writing(self.csv):
            atomic_write_text(self.csv, self._text([self.columns, *rows]))

    def append(self, rows: Sequence[dict[str, Any]]) -> None:
        """Append one trial's rows with a single write, then fsync."""
        data = self._text([[_cell(r.get(c)) for c in self.columns] for r in rows]).encode("utf-8")
        with writing(self.csv):
            fd = os.open(self.csv, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
                os.fsync(fd)
            finally:
                os.close(fd)

    def saved_statuses(self) -> set[str]:
        """The statuses in the saved CSV (empty when there is none or it cannot be read)."""
        try:
            df = pd.read_csv(self.csv, usecols=["status"], keep_default_na=False)
        except (OSError, ValueError, pd.errors.ParserError):
            return set()
        return set(df["status"].astype(str))

    def first_error_if_all_failed(self) -> str | None:
        """The status of the first trial (by σ index, trial) when every saved trial failed, else None."""
        rows = self._load_rows()
        ist, ii, it = (self.columns.index(c) for c in ("status", "sigma_index", "trial"))
        if not rows or not all(is_error(r[ist]) for r in rows):
            return None
        first = min(rows, key=lambda r: (int(r[ii]), int(r[it])))
        return first[ist].removeprefix(f"{ERROR}: ")

    def finalize(self) -> None:
        """Rewrite the CSV sorted by (σ index, trial, set) unless it already is."""
        rows = self._load_rows()
        ii, it, iset = (self.columns.index(c) for c in ("sigma_index", "trial", "constraint_set"))
        order = sorted(rows, key=lambda r: (int(r[ii]), int(r[it]), self.sets.index(r[iset])))
        if order != rows:
            self._rewrite(order)


def _row(line: str) -> list[str]:
    """One CSV line's fields; [] for a line holding bytes that were not UTF-8 or a NUL (a damaged line)."""
    if "\ufffd" in line or "\x00" in line:
        return []
    try:
        return next(csv.reader([line]), [])
    except csv.Error:
        return []


def load_trials(out: str | Path, trials: int | None = None) -> pd.DataFrame:
    """``trials.csv`` as a DataFrame (booleans parsed), optionally only trials < ``trials``."""
    path = Path(out) / CSV_NAME
    if not path.exists():
        raise ReportError(f"no {CSV_NAME} in {out}")
    df = pd.read_csv(path, keep_default_na=False, na_values=["nan", ""])
    for c in BOOL_COLUMNS:
        if c in df:
            df[c] = df[c].astype(str) == "True"
    if trials is not None:
        df = df[df["trial"] < trials].reset_index(drop=True)
    return df


def is_error(status: object) -> bool:
    """Whether a saved status is that of a trial that raised (it starts with ``ERROR``)."""
    return str(status).startswith(ERROR)


def solved_rows(df: pd.DataFrame) -> pd.Series:
    """Mask of the trials of ``df`` that did not raise (a solver status, whatever it is)."""
    return ~df["status"].astype(str).str.startswith(ERROR)


def redo_matches(status: str, redo: Sequence[str]) -> bool:
    """Whether a saved status is one of ``redo``: equal to an entry; "Error" or "Failed": every status so starting."""
    return any(status == r or (r in (ERROR, "Failed") and status.startswith(r)) for r in redo)


def _starts_with(path: Path, prefix: str) -> bool:
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read(len(prefix)) == prefix
    except OSError:
        return False


def _short(v: Any, n: int = 80) -> str:
    s = json.dumps(v, ensure_ascii=False)
    return s if len(s) <= n else s[: n - 1] + "…"
