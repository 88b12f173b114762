"""``python -m delegation`` runs the CLI."""

import sys

from delegation.cli import main

sys.exit(main())
