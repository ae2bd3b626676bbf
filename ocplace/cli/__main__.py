"""`python -m ocplace.cli`: the console script without its installed entry point."""

import sys

from ocplace.cli import main

sys.exit(main())
