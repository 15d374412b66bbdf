"""``python -m torchtea.cli``: the ``torchtea`` command."""
import sys

from . import main

sys.exit(main())
