"""The ``deepc`` command line: the parser and dispatch (``main``) and one module per subcommand (``run``, ``eval``,
``mesh``, ``probe``, ``train``), with the run's progress bar (``progress``), model cards written by ``deepc train``
(``model_card``) and the numba cache warm-up that setup runs (``compile_cache``). ``deepc view``, ``replay`` and
``regress`` live in ``workbench.viewer``, ``workbench.rerun`` and ``workbench.regress``."""
