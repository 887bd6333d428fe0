"""numba compilation options shared by the simulator's kernels (``pipeline/sim/*_kernels.py``).

Compiled once per machine and cached next to the sources (``__pycache__``); IEEE arithmetic (no fastmath), so the
same inputs give the same bits; numpy's error model (division by zero gives inf/NaN rather than raising), which
the kernels rely on for rays that miss.
"""

NJIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}
