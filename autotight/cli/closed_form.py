"""The closed-form table in ``discover``'s output: text after its table, and ``--latex FILE``."""

from __future__ import annotations

import argparse

from ..io import atomic_write_text
from ..outpaths import writing
from ..threads import single_blas_thread


@single_blas_thread
def closed_form_output(problem, ds, args: argparse.Namespace) -> None:
    """Print the table "discovered family | closed form | paper family | relation" of the set ``ds`` (not with
    --json), and write its LaTeX to ``args.latex`` when given."""
    latex = getattr(args, "latex", None)
    if (args.json and latex is None) or getattr(ds, "pairs", None) is None:  # nothing asked, or no set
        return
    from ..closed_form.table import family_table, text
    from ..closed_form.tex import document

    tab = family_table(problem, ds)
    if not args.json:
        print("\nclosed forms (modulo the primary constraints):")
        print(text(tab))
    if latex is not None:
        with writing(latex):
            atomic_write_text(latex, document(tab))
        if not args.json:
            print(f"LaTeX saved to {latex}")
