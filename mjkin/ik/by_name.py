"""The IK methods by name (``method="lm"``)."""

from __future__ import annotations

from .analytic import Analytic2
from .ccd import CCD
from .lm import DLS, LM, Auto, PInv, Transpose
from .method import Method
from .optimize import Optimize
from .reach import Reach

METHODS: dict[str, type[Method]] = {m.name: m for m in (Auto, LM, DLS, PInv, Transpose, CCD, Analytic2, Optimize,
                                                        Reach)}
