"""Discovered families in closed form: exact polynomials in a factor's data, normalised modulo the primary
constraints, printed in named symbols beside the paper's families (``table.family_table``)."""
