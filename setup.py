"""The one compiled piece setuptools builds: the C call path of one-q poses (``mjkin/kinematics/_posecall.c``).

Metadata lives in ``pyproject.toml``. The extension is optional: without a C compiler
the install goes on and ``Tree.pose`` calls numba's entry from Python instead (slower
by about 0.4 µs a call, the same numbers).
"""

import numpy
from setuptools import Extension, setup

setup(ext_modules=[Extension("mjkin.kinematics._posecall", ["mjkin/kinematics/_posecall.c"],
                             include_dirs=[numpy.get_include()], optional=True)])
