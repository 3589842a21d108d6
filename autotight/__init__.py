"""autotight: find the redundant constraints that make Shor's SDP relaxation tight.

The public API (see ``docs/api.md``):

>>> import autotight as at
>>> result = at.discover("pose_averaging", {"M": 5})                # learn, tighten, reduce, check
>>> result.constraint_set.save("pose_set.json")
>>> out = at.solve("pose_averaging", {"M": 5}, seed=3,
...                constraints=at.ConstraintSet.load("pose_set.json"))
>>> out.tight, out.log_svr
"""

from ._version import __version__
from .api import certify, discover, load_problem, solve
from .check import check_sufficient
from .checks import check_problem
from .constraint_set import ConstraintSet
from .errors import AutotightError
from .model import Constraint, Factor, Model, QuadForm, Variables
from .pipeline import SolveResult
from .problem import Instance, LocalResult, Meta, Param, Problem
from .sdp.config import ClarabelOptions, IpmOptions, SolverConfig, SolverOptions
from .tightness import Criteria, Verdict
from .validity import InvalidConstraintError

__all__ = ["__version__", "load_problem", "solve", "discover", "certify", "check_problem", "check_sufficient",
           "ConstraintSet", "SolveResult", "Criteria", "Verdict", "SolverConfig", "SolverOptions", "AutotightError",
           "InvalidConstraintError", "ClarabelOptions", "IpmOptions",
           "Problem", "Param", "Meta", "Instance", "LocalResult", "Model",
           "Variables", "Factor", "QuadForm", "Constraint"]
