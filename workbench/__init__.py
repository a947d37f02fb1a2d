"""DeepC Workbench user interfaces: the ``deepc`` command line, rerun streams, the viser viewer.

- ``cli``: the parser of every command and the dispatch to its module: ``run_command`` (flags in
  ``run_flags``, options made from them in ``run_options``), ``eval_command``, ``train_command`` (flags in
  ``train_flags``), ``regress/`` (with its HTML report in ``report/``), ``viewer`` and ``replay``.
- Runs: ``run_maps`` reads a run's per-view maps (through ``engine/run_folder.py``); ``map_images`` turns
  maps into pictures; ``run_recording``, ``recording`` and ``stream`` write rerun recordings.
- The viewer: ``session`` (stage caches, no viser), ``scheduler`` (newest request wins), ``viewer_panel``
  (controls), ``viewer_export`` (files it writes) and ``viewer`` (the app).
"""
