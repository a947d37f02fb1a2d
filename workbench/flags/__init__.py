"""Options dataclasses as command-line flags and back: the generic mapping and ``--set STAGE.NAME=VALUE``
(``options``), ``deepc run``'s flags (``run``) and the options made from them (``run_options``), ``deepc train``'s
flags (``train``)."""
