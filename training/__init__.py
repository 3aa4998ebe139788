"""envfuse training package (see DESIGN.md §2)."""
