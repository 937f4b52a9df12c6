"""Defer the numpy subpackages that scipy's array-API shim touches but stw never uses.

Importing scipy.sparse imports its vendored array_api_compat, which clones the numpy namespace
with ``hasattr(numpy, name)`` over ``dir(numpy)``. numpy loads its subpackages lazily, so that
walk imports numpy.f2py, numpy.testing and numpy.ctypeslib (with unittest, logging and
concurrent.futures), which no solve reads. (It loads numpy.ma and numpy.polynomial too, but
np.unique and the Gauss-Legendre rule read those within the first command anyway.)

Registering each of them first as a standard-library lazy module (importlib.util.LazyLoader)
keeps the clone cheap: the module object exists, and its code runs the first time any of its
attributes is read, so a program that does use one gets the real module, only later.
Called only where `stw` owns its process (a library caller's numpy is left alone).
"""

from __future__ import annotations

import importlib.util
import sys

UNUSED_SUBPACKAGES = ("f2py", "testing", "ctypeslib")


def defer_unused_numpy_subpackages() -> list[str]:
    """Register numpy's unused subpackages as lazy modules, unless something already imported
    them; returns the names deferred. numpy itself is imported (every command that calls this
    loads it anyway)."""
    import numpy

    deferred = []
    for name in UNUSED_SUBPACKAGES:
        full = f"numpy.{name}"
        if full in sys.modules:
            continue
        spec = importlib.util.find_spec(full)
        if spec is None or spec.loader is None:     # a numpy without it: nothing to defer
            continue
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[full] = module
        spec.loader.exec_module(module)             # lazy: runs the code on first attribute read
        setattr(numpy, name, module)                # so numpy's own __getattr__ is not consulted
        deferred.append(full)
    return deferred
