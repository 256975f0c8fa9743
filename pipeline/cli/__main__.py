"""``python -m pipeline.cli``: the ``biasgt`` command."""

import sys

from pipeline.cli.app import main

sys.exit(main())
