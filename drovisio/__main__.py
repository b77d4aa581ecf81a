"""``python -m drovisio`` is the same as the ``drovisio`` command."""

import sys

from drovisio.cli import main

sys.exit(main())
