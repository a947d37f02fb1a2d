"""``python -m workbench.cli ARGS``: the same as ``deepc ARGS``."""

import sys

from workbench.cli.main import main

sys.exit(main())
