"""One module per CLI command family; see :mod:`pipeline.cli`."""
