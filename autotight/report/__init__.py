"""Noise-sweep tightness reports: ``autotight report PROBLEM`` (figures, report.md, report.html)."""
