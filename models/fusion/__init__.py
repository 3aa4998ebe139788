"""Event-driven fusion: PDR steps predict, GNSS and acoustic fixes update, the environment sets the noise.

Pure maths on in-memory event streams; :mod:`walks` fills the event columns
from a walk's readers. Modules:

* ``events`` — the event streams (steps, GNSS, acoustic, standing), class evidence over time
  (``ClassTrack``) and over the site (``ClassMap``), and their merge;
* ``core`` — the one compiled Kalman filter core (time update, PDR step, Joseph-form update, NIS, gate,
  Huber, the VB-AKF's R): every filter below runs it;
* ``ekf`` — ``EventEKF``, its settings (``EkfConfig``) and records (``FilterRun``);
* ``imm`` — the interacting multiple model filter over environment classes;
* ``noise`` — the measurement-noise policies (fixed, quality, per class, VB-AKF); ``context`` — the error
  model in context: white part, Gauss–Markov bias and outlier prior per (class, GGA quality);
* ``smoother`` — RTS smoothing of any run; ``consistency`` — NEES / NIS and their χ² bounds;
* ``model`` — the fitted fusion model (``FusionModel``) and its pickle-free bundle.

Feed and read::

    ev = merge_events(steps=StepEvents(t_s, step_length_m, heading_rad),
                      gnss=GnssEvents(t_s, east_m, north_m, cov_m2, quality=..., hdop=..., gst_sigma_m=...),
                      acoustic=AcousticEvents(t_s, east_m, north_m, cov_m2),
                      stands=StandIntervals(start_s, end_s))
    run = EventEKF(EkfConfig(outlier="gate"), noise=FixedNoise().fit(gnss_err, ac_err), method="kf").run(ev)
    run.x, run.P                  # posterior per event: (m, n), (m, n, n)
    run.K, run.nu, run.S, run.nis, run.dx, run.accepted   # per update, for the BP corrector
    smooth = rts_smooth(run)      # "<method>+rts"

Which filter and policy each method of :mod:`walks.methods` builds:

=================  ===========================================================
``kf``             ``EventEKF(noise=FixedNoise().fit(...))``
``kf_quality``     ``EventEKF(noise=QualityNoise().fit(...))``
``kf_map``         ``EventEKF(noise=PerClassNoise().fit(...)).run(ev, class_at=ClassMap(...))``
``adaptive_nobp``  ``EventEKF(EkfConfig(outlier="mixture"), ContextNoise().fit(...)).run(ev, classes=...)``
``aekf``           ``EventEKF(noise=VBAdaptiveNoise().fit(...))``
``imm``            ``IMMFilter(PerClassNoise().fit(...)).run(ev, classes=...)``
=================  ===========================================================
"""

from models.fusion.consistency import chi2_bounds, in_bounds_share, nees, nis_summary
from models.fusion.ekf import EkfConfig, EventEKF, FilterError, FilterResume, FilterRun
from models.fusion.events import (ACOUSTIC, GNSS, KIND_NAMES, STEP, AcousticEvents, ClassMap, ClassTrack, EventError,
                                  EventStream, GnssEvents, StandIntervals, StepEvents, merge_events)
from models.fusion.imm import IMMFilter
from models.fusion.context import ContextNoise
from models.fusion.noise import FixedNoise, NoiseError, PerClassNoise, QualityNoise, VBAdaptiveNoise, second_moment_m2
from models.fusion.smoother import SmoothedTrack, fixed_lag_smooth, rts_smooth

__all__ = [
    "STEP", "GNSS", "ACOUSTIC", "KIND_NAMES", "StepEvents", "GnssEvents", "AcousticEvents", "StandIntervals",
    "ClassTrack", "ClassMap", "EventStream", "merge_events", "EventError",
    "EkfConfig", "EventEKF", "FilterRun", "FilterResume", "FilterError", "IMMFilter",
    "FixedNoise", "QualityNoise", "PerClassNoise", "ContextNoise", "VBAdaptiveNoise", "NoiseError",
    "second_moment_m2", "SmoothedTrack", "rts_smooth", "fixed_lag_smooth", "nees", "chi2_bounds", "in_bounds_share", "nis_summary",
]
