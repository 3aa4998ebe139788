"""envfuse fingerprints package (see DESIGN.md §2)."""
