"""numba's ``njit``, compiled (or loaded from numba's cache) on a kernel's first call.

Importing numba and loading the first cached kernel cost 0.2 s and 0.3 s on this machine (LLVM's set-up;
measured before and after, issue 39): more than the whole static solve of a small sample, which never calls
a kernel (its products come from the assembled matrix).  A module that defines kernels with this ``njit``
imports without numba; the first call compiles the kernel with numba's own ``njit(**options)`` and every
later call goes straight to it.  A kernel may call another of these kernels: the callee is compiled first and
the caller compiled against its dispatcher (numba types only its own dispatchers).
"""
from __future__ import annotations

import functools
import types


def njit(**options):
    """``@njit(cache=True, nogil=True)`` as numba's, numba imported and the kernel compiled on first use."""
    def wrap(fn):
        compiled = None

        def kernel():
            """numba's dispatcher of ``fn``, made on first use; the kernels ``fn`` calls made before it."""
            nonlocal compiled
            if compiled is None:
                import numba

                callees = {name: fn.__globals__[name].kernel() for name in fn.__code__.co_names
                           if hasattr(fn.__globals__.get(name), "kernel")}
                f = fn if not callees else types.FunctionType(fn.__code__, {**fn.__globals__, **callees}, fn.__name__,
                                                              fn.__defaults__, fn.__closure__)
                compiled = numba.njit(**options)(f)
            return compiled

        @functools.wraps(fn)
        def call(*args):
            return (compiled or kernel())(*args)

        call.kernel = kernel
        return call
    return wrap
