"""The ``autotight`` command line: its parser, its verbs, and its error rule.

Verbs: ``list | solve | discover | report | check | check-module | certify | templates | export``, one
module each in this package; what they share is in ``options``.  The CLI is a thin layer over the
Python API (``autotight.api``).  Errors: an input error or a failed solve (any
``autotight.errors.AutotightError``) prints one line ``autotight: error: …`` and exits with status 2;
anything else is a bug and raises with its traceback.  ``--debug`` shows the traceback of every error.
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn, Sequence

from ..errors import AutotightError
from . import certify, check, check_module, discover, export, list_problems, report, solve, templates
from .options import add_problem_args

#: the verbs' modules, in the order of ``autotight --help``
VERBS = (list_problems, solve, discover, report, check, check_module, certify, templates, export)


class _Parser(argparse.ArgumentParser):
    """argparse with the CLI's error rule: one line ``autotight: error: …``, exit status 2."""

    def error(self, message: str) -> NoReturn:
        where = self.prog.removeprefix("autotight").strip()
        print(f"autotight: error: {where + ': ' if where else ''}{message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(2)


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="autotight", description="Make SDP relaxations of estimation problems tight: "
                 "list | solve | discover | report | check | check-module | certify | templates | export",
                 epilog="--debug (anywhere on the line): show the traceback of any error")
    sub = ap.add_subparsers(dest="cmd", required=True)
    for verb in VERBS:
        verb.register(sub, add_problem_args)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    try:
        return int(args.func(args) or 0)
    except AutotightError as e:
        if debug:
            raise
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        print(f"autotight: error: {msg}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. piped into `head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("autotight: interrupted", file=sys.stderr)
        return 130
