"""``python -m gns_framework.cli``: the ``gns`` command (used by torchrun and tests)."""

import sys

from . import main

sys.exit(main())
