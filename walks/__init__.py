"""One walk: read it, turn it into filter inputs, run every fusion method on it, score and write its tracks.

The floor between the models and what fits or runs them (``training``,
``pipeline``). Which module to open for what:

* ``walks.reader`` — :func:`~walks.reader.read_walk`: a walk directory's files (NMEA, audio, IMU, truth)
  read once, every source on the walk's time base;
* ``walks.inputs`` — :func:`~walks.inputs.walk_inputs`: the event stream the filters take and the
  environment classifier's evidence over time;
* ``walks.methods`` — the registry of fusion methods (name → builder) and the built-in ones;
  :func:`~walks.methods.run_methods` runs any of them on one walk;
* ``walks.graph_methods`` — the factor-graph methods (GTSAM) and the RTK/PDR EKF, registered on import
  (imported below, so every user of the registry sees them);
* ``walks.uwb_methods`` — the UWB methods (the UWB fixes alone, Zhou et al.'s UWB AOA + PDR filter),
  registered on import after the graph methods;
* ``walks.foot_methods`` — ``foot_ins_fkf``, the foot INS in a federated filter with UWB and heading (issue 26),
  registered on import after the UWB methods;
* ``walks.acoustic_ranges`` — every frame's beacon ranges, for tightly coupled fusion;
* ``walks.fuse`` — :func:`~walks.fuse.fuse_walk`: files to tracks, the path ``run`` and ``evaluate`` share;
* ``walks.score`` — a track against truth: errors, NEES, metric rows;
* ``walks.track`` — :class:`~walks.track.Track` and how a track is written (CSV, GeoJSON).
"""

__all__ = ["reader", "inputs", "methods", "graph_methods", "uwb_methods", "foot_methods", "acoustic_ranges", "fuse",
           "score", "track"]

from walks import graph_methods  # noqa: E402,F401  (registers the graph methods after the built-in ones)
from walks import uwb_methods  # noqa: E402,F401  (registers the UWB methods after the graph methods)
from walks import foot_methods  # noqa: E402,F401  (registers foot_ins_fkf after them)
