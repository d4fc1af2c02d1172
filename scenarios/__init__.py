"""scenarios: the simulated world, renderer, rover, camera server and scoring.

It runs the product against its world, so it may import the companion, rescue-hq,
mavlink_io and fusion; nothing in the product imports it (tests/test_layers.py).

The simulator renders with numpy in one process that also starts and restarts child
processes (the chaos mission, the live demo). OpenBLAS's worker threads and fork do
not mix: in the chaos mission a companion restart was forked while the camera
server's render thread was inside a matrix product, and the product never returned
(two threads at 100 % CPU, the render thread's stack in ``d @ inv.T``): the camera
stayed silent for the rest of the mission (2026-11-27, twice, from the same SIGKILL
442 s in). Its products are small (a few thousand rays by 3 x 3) and gain nothing
from threads, so BLAS runs single-threaded here unless the caller says otherwise.
This only holds when scenarios is imported before numpy (the ``rescue-sim`` and
``python -m bench.chaos`` entry points do so).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
