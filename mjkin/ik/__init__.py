"""Inverse kinematics: the front door :func:`solve` and one module per method.

``kernel`` holds the compiled Jacobian-based solvers (``lm``/``auto``, ``dls``,
``pinv``, ``transpose``); ``ccd``, ``analytic`` and ``optimize`` the others.
"""

from .solve import METHODS, History, Result, singular_values, solve

__all__ = ["METHODS", "History", "Result", "singular_values", "solve"]
