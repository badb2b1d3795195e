"""``python -m jaxflex`` runs the command line."""

import sys

from jaxflex.cli import main

sys.exit(main())
