"""Inverse kinematics: :class:`Problem` (goals compiled once, solved again and again), one module per method.

``lm`` holds the Jacobian methods (:class:`LM`, :class:`Auto`, :class:`DLS`,
:class:`PInv`, :class:`Transpose`) run by one compiled loop (``loop``, with a branch per
goal kind; ``generated`` copies it for a kind the user registers); ``ccd``, ``reach``, ``analytic`` and
``optimize`` the others; ``result`` what a solve returns.
"""

from .analytic import Analytic2
from .by_name import METHODS
from .ccd import CCD
from .evaluate import evaluate, singular_values
from .lm import DLS, LM, Auto, Jacobian, PInv, Transpose
from .method import Method
from .optimize import Optimize
from .problem import Problem
from .reach import Reach
from .result import History, Result
from .solve import solve

__all__ = ["CCD", "DLS", "LM", "METHODS", "Analytic2", "Auto", "History", "Jacobian", "Method", "Optimize", "PInv",
           "Problem", "Reach", "Result", "Transpose", "evaluate", "singular_values", "solve"]
