"""``python -m biasgt.cli``: the ``biasgt`` command."""

import sys

from biasgt.cli.app import main

sys.exit(main())
