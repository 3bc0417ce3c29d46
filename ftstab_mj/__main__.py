"""``python -m ftstab_mj`` = the ``ftstab`` command."""

import sys

from ftstab_mj.cli import main

sys.exit(main())
