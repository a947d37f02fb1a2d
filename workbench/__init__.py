"""DeepC Workbench user interfaces, one package per family: ``cli`` (the ``deepc`` command, one module per
subcommand), ``flags`` (options as flags), ``rerun`` (streams, recordings, replay), ``viewer`` (the viser viewer,
its session and inspector), ``trace`` (probe traces as figures), ``maps`` (a run's maps read and drawn) and
``regress`` (``deepc regress`` and its HTML report). ``docs/architecture.md`` has the module table."""
