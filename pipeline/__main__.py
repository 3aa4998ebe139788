"""``python -m pipeline`` runs the envfuse CLI."""

import sys

from pipeline.cli import main

sys.exit(main())
