"""DeepC Workbench user interfaces: the ``deepc`` command line, rerun streams, the viser viewer."""
