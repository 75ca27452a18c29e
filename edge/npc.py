"""numpy's C functions without their Python-level wrappers, for the frame's hot path: the same functions, so the
same results (the wrapper only forwards). ``count_nonzero(a)`` is ``np.count_nonzero(a)`` without ``axis``."""

from __future__ import annotations

import numpy as np

try:  # numpy 2
    from numpy._core.multiarray import count_nonzero
except ImportError:  # pragma: no cover - numpy 1.26
    try:
        from numpy.core.multiarray import count_nonzero
    except ImportError:
        count_nonzero = np.count_nonzero

__all__ = ["count_nonzero"]
