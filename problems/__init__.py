"""Estimation problems, one module each.  See ``autotight.problem`` for what a module defines."""
