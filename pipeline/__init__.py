"""Running envfuse: the CLI, reading walks, reports and plots. Nothing imports this package.

``walk_data`` is the spine: :func:`~pipeline.walk_data.read_walk` reads a walk
directory once and returns every source on the walk's time base (the report,
the demo, and the fusion commands stand on it). ``walk_report`` puts a walk's
sources against its truth; ``plots`` draws sites and walks; ``cli`` is the
``envfuse`` command line, one module per command family in ``commands/``
(found automatically), with argument types in ``args``.
"""

__all__ = ["walk_data", "walk_report", "plots", "cli", "args", "commands"]
