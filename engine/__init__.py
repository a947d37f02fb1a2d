"""DeepC Workbench engine: PatchMatch MVS with deep confidence, as pure computation.

The engine never imports a viewer; it reports progress to observers. I/O lives in ``engine.io``.
"""

import os

# numba tries TBB first and warns when the system's TBB is older than it supports (Debian 12 ships 2021.8, e.g.
# with OpenCV); OpenMP first, the layer it then falls back to, keeps the output clean. NUMBA_THREADING_LAYER wins.
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp tbb workqueue")

__version__ = "0.1.0"
