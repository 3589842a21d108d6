"""Exceptions with one-line messages; the CLI prints them without a traceback."""


class AutotightError(Exception):
    """Base class for errors caused by bad input or a problem that cannot be done."""


class ProblemDefinitionError(AutotightError):
    """A problem module is malformed (missing part, inconsistent block sizes, …)."""


class ProblemModuleError(ProblemDefinitionError):
    """A part of a problem module raised, or returned the wrong type or shape.

    The message names the module, the part and the exception; the original exception is the
    ``__cause__`` (raised ``from`` it), so its traceback is kept for debugging.
    """


class ParameterError(AutotightError):
    """A problem parameter is missing, unknown or out of range."""


class SolverConfigError(ParameterError):
    """A ``SolverConfig`` field or a backend's option is unknown, out of range, or names a solver that is
    not installed."""


class LearningError(AutotightError):
    """Constraint learning cannot proceed (no spectral gap, infeasible samples, …)."""


class SolverError(AutotightError):
    """An SDP or local solve failed in a way that leaves no usable result."""
