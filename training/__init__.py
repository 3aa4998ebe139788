"""envfuse training package (see docs/design.md §2)."""
