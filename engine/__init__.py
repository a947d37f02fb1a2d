"""DeepC Workbench engine: PatchMatch MVS with deep confidence, as pure computation.

The engine never imports a viewer; it reports progress to observers. I/O lives in ``engine.io``.
"""

__version__ = "0.1.0"
