"""numpy's clip ufunc itself, for per-tick code.

``np.clip`` dispatches through Python (a few µs); the ufunc it ends in is one C call, the same
numbers (min(max(x, lo), hi)). It lives in numpy's private ``_core`` (``core`` before numpy 2).
"""

try:
    from numpy._core.umath import clip
except ImportError:  # numpy < 2
    from numpy.core.umath import clip

__all__ = ["clip"]
