"""``python -m fleet.cli``: the same as the ``drona`` command."""

import sys

from fleet.cli import main

sys.exit(main())
