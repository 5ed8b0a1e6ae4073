"""``python -m poromech`` is the ``poromech`` command."""

import sys

from poromech.cli import main

sys.exit(main())
