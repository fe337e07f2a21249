"""``python -m hexsos_plugins`` is the ``hexsos`` command."""

import sys

from .cli import main

sys.exit(main())
