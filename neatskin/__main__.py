"""`python -m neatskin` runs the CLI."""

import sys

from neatskin.cli import main

sys.exit(main())
