"""numba compilation options of the inpainting kernels (``inpaint/c2f_kernels.py``).

The same choices as the simulator's kernels (which ``inpaint`` may not import): compiled once per machine and cached
next to the sources (``__pycache__``); IEEE arithmetic (no fastmath), so the same input gives the same bits; numpy's
error model. Kernels are single-threaded (no ``parallel``): the result never depends on the thread count.
"""

NJIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}
