"""The one numba decorator of mwbx's host loops.

Every host-side kernel (the codec's bit loops, the native backend's and the
refinement's per-world loops, the per-step bookkeeping) compiles with it:
``cache=True`` keeps the machine code on disk between runs, and
``nogil=True`` lets the native backend's threads (one world each) and a
compressing thread run at once.
"""

from __future__ import annotations

import numba

host_jit = numba.njit(cache=True, nogil=True)
