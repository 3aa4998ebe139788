"""``python -m pipeline`` runs the envfuse CLI."""

import sys

from .cli import main

sys.exit(main())
