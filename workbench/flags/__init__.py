"""Options dataclasses as command-line flags and back: the generic mapping (``options``), the one parser of
``--set STAGE.NAME=VALUE`` (``assignments``), the listing of every such option (``help_options``: ``deepc run
--help-options``), ``deepc run``'s flags (``run``) and the options made from them (``run_options``: its stages are
``PipelineOptions``'s), ``deepc train``'s flags (``train``)."""
