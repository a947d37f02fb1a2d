"""Code that the tests and the benchmarks share and the runtime never imports.

Plain-numpy references of the numba kernels, synthetic inputs, fault injection and the benchmark
harness live here so that ``engine`` and ``workbench`` hold only what a run needs. Installed with the
package (``pip install -e .``), so tests and benchmark scripts import it without editing ``sys.path``.
"""
