"""numba's ``njit``, compiled (or loaded from numba's cache) on a kernel's first call.

Importing numba and loading the first cached kernel cost 0.2 s and 0.3 s on this machine (LLVM's set-up;
measured before and after, issue 39): more than the whole static solve of a small sample, which never calls
a kernel (its products come from the assembled matrix).  A module that defines kernels with this ``njit``
imports without numba; the first call compiles the kernel with numba's own ``njit(**options)`` and every
later call goes straight to it.  A kernel called from another kernel needs numba's dispatcher itself: such
modules (the aerogel's aggregation) import numba directly.
"""
from __future__ import annotations

import functools


def njit(**options):
    """``@njit(cache=True, nogil=True)`` as numba's, numba imported and the kernel compiled on first use."""
    def wrap(fn):
        compiled = None

        @functools.wraps(fn)
        def call(*args):
            nonlocal compiled
            if compiled is None:
                import numba

                compiled = numba.njit(**options)(fn)
            return compiled(*args)
        return call
    return wrap
