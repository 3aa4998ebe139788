"""Readers and signal processing: pure functions of raw device data.

This package imports nothing else of envfuse; every other package may import it.
"""
