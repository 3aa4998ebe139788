"""Synthetic substations that write exactly what real devices write.

Writes the on-disk formats of DESIGN.md §4 and nothing else; downstream code
reads those files, never this package's internals.
"""
