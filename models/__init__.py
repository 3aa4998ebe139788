"""envfuse models package (see DESIGN.md §2)."""
