"""agrivio's application layer: bags and simulator in, runs and reports out (the ``agrivio`` CLI).

Runs execute several single-threaded VIO processes side by side; OpenBLAS's spinning worker threads then only
steal cores from each other (measured: a VIO frame went from ≈80 ms to ≈350 ms with two runs on two cores), so
the pipeline pins BLAS to one thread unless the user set it. This must happen before numpy is first imported,
which is why it lives here.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
