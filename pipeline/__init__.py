"""Running envfuse: the command line, batch evaluation on Dask, reports and plots. Nothing imports this package.

Which module to open for what:

* ``cli`` — the ``envfuse`` command line; one module per command family in ``commands/`` (found
  automatically), with argument types and output checks in ``args``;
* ``evaluate`` — ``envfuse evaluate``: every method on many walks (:func:`walks.fuse.fuse_walk` per walk),
  ``metrics.csv`` and the summary; ``evaluate_plots`` — its figures;
* ``parallel`` — one task per walk, serially or on a Dask cluster;
* ``benchmark`` — a seeded split end to end (``envfuse benchmark``, ``envfuse demo``);
* ``site_map`` — the site's environment map from its drawing, for the map baseline and the site plot
  (the one place below the CLI that reads simulator code);
* ``walk_report`` — one walk's raw sources against its truth (``envfuse report walk``);
* ``plots``, ``env_plots`` — figures of sites, walks and environment models; ``tables`` — CSV helpers.
"""

__all__ = ["cli", "args", "commands", "evaluate", "evaluate_plots", "parallel", "benchmark", "site_map",
           "walk_report", "plots", "env_plots", "tables"]
