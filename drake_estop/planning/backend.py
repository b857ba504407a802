"""Optional numba backend for the stop-parameter solver (the pattern of pymanoid's optional QP backends).

The solver (:mod:`~drake_estop.planning.stop_condition`, :mod:`~drake_estop.planning.newton`,
:mod:`~drake_estop.planning.solver`) is written once, in the subset of Python that numba
compiles: scalar loops over float64 arrays, no Python objects. :func:`jit` compiles it with
``numba.njit(cache=True)`` where numba is importable and leaves it plain Python otherwise,
so the same source runs either way:

* ``DRAKE_ESTOP_PURE_PYTHON=1`` (or numba's own ``NUMBA_DISABLE_JIT=1``) in the environment,
  read at import: plain Python, for debugging and for the tests that compare both paths;
* numba missing or broken: plain Python, about 30x slower, same plans.

The functions guard every division and logarithm that numba would let through as inf / nan
(``error_model="numpy"``) and plain Python would raise on, so both paths return the same
values and status codes. Compiled code is cached next to the sources (``__pycache__``):
the first plan after an install compiles for tens of seconds, later processes load the
cache (:func:`drake_estop.planning.planner.warm_up` does that before the robot walks).
numba checks a cached function against its own source file only, while the solver's entry
point inlines code from three files; :func:`jit` therefore stamps every cache entry with the
hash of all of them (:data:`SOURCES`), so an edit of any one recompiles them all.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

try:
    import numba
except ImportError:  # numba missing or broken: the solver runs as plain Python
    numba = None

COMPILED = (numba is not None and not os.environ.get("DRAKE_ESTOP_PURE_PYTHON")
            and not numba.config.DISABLE_JIT)
"""True where :func:`jit` compiles (numba importable, neither ``DRAKE_ESTOP_PURE_PYTHON`` nor
``NUMBA_DISABLE_JIT`` set)."""

_OPTIONS = dict(cache=True, nogil=True, error_model="numpy")
SOURCES = ("backend.py", "stop_condition.py", "newton.py", "solver.py")
"""The modules of the compiled solver (in this folder)."""


def _sources_hash() -> str:
    digest = hashlib.sha256()
    try:
        for name in SOURCES:
            digest.update(Path(__file__).with_name(name).read_bytes())
    except OSError:  # sources not readable as files: numba's own stamps only
        return ""
    return digest.hexdigest()


def jit(function):
    """``numba.njit(cache=True, nogil=True, error_model="numpy")`` if :data:`COMPILED`, else ``function``."""
    if not COMPILED:
        return function
    dispatcher = numba.njit(**_OPTIONS)(function)
    try:  # numba's cache index is stamped with the hash of the function's own file: add the others'
        index = dispatcher._cache._cache_file
        index._source_stamp = (index._source_stamp, _SOURCES_HASH)
    except AttributeError:  # another numba version: its own stamp only
        pass
    return dispatcher


_SOURCES_HASH = _sources_hash() if COMPILED else ""


def python_function(function):
    """The plain-Python function behind a :func:`jit` function (itself where not compiled)."""
    return getattr(function, "py_func", function)
