"""One walk: read it, turn it into filter inputs, run every fusion method on it, score and write its tracks.

The floor between the models and what fits or runs them (``training``,
``pipeline``). Which module to open for what:

* ``walks.reader`` — :func:`~walks.reader.read_walk`: a walk directory's files (NMEA, audio, IMU, truth)
  read once, every source on the walk's time base;
* ``walks.inputs`` — :func:`~walks.inputs.walk_inputs`: the event stream the filters take and the
  environment classifier's evidence over time;
* ``walks.methods`` — the registry of fusion methods (name → builder) and the built-in ones;
  :func:`~walks.methods.run_methods` runs any of them on one walk;
* ``walks.fuse`` — :func:`~walks.fuse.fuse_walk`: files to tracks, the path ``run`` and ``evaluate`` share;
* ``walks.score`` — a track against truth: errors, NEES, metric rows;
* ``walks.track`` — :class:`~walks.track.Track` and how a track is written (CSV, GeoJSON).
"""

__all__ = ["reader", "inputs", "methods", "fuse", "score", "track"]
