"""Event-driven fusion filters: PDR steps predict, GNSS and acoustic fixes update (DESIGN.md §7).

Pure maths on in-memory event streams; the pipeline fills the event columns
from the readers. Feed and read::

    ev = merge_events(steps=StepEvents(t_s, step_length_m, heading_rad),
                      gnss=GnssEvents(t_s, east_m, north_m, cov_m2, quality=..., hdop=..., gst_sigma_m=...),
                      acoustic=AcousticEvents(t_s, east_m, north_m, cov_m2),
                      stands=StandIntervals(start_s, end_s))
    run = EventEKF(EkfConfig(outlier="gate"), noise=FixedNoise().fit(gnss_err, ac_err), method="kf").run(ev)
    run.x, run.P                  # posterior per event: (m, n), (m, n, n)
    run.K, run.nu, run.S, run.nis, run.dx, run.accepted   # per update, for the BP corrector
    smooth = rts_smooth(run)      # "<method>+rts"

Methods of issue 14 and what builds them:

=================  ===========================================================
``kf``             ``EventEKF(noise=FixedNoise().fit(...))``
``kf_quality``     ``EventEKF(noise=QualityNoise().fit(...))``
``kf_map``         ``EventEKF(noise=PerClassNoise().fit(...)).run(ev, class_at=f)``
``adaptive_nobp``  ``EventEKF(noise=PerClassNoise().fit(...)).run(ev, classes=ClassTrack(...))``
``aekf``           ``EventEKF(noise=VBAdaptiveNoise().fit(...))`` (or ``SageHusaNoise``)
``imm``            ``IMMFilter(PerClassNoise().fit(...)).run(ev, classes=...)``
=================  ===========================================================
"""

from models.fusion.consistency import chi2_bounds, in_bounds_share, nees, nis_summary
from models.fusion.ekf import EkfConfig, EventEKF, FilterError, FilterRun, run_ekf
from models.fusion.events import (ACOUSTIC, GNSS, KIND_NAMES, STEP, AcousticEvents, ClassTrack, EventError,
                                  EventStream, GnssEvents, StandIntervals, StepEvents, merge_events)
from models.fusion.imm import IMMFilter
from models.fusion.noise import (FixedNoise, NoiseError, PerClassNoise, QualityNoise, SageHusaNoise,
                                 VBAdaptiveNoise, second_moment_m2)
from models.fusion.smoother import SmoothedTrack, rts_smooth

__all__ = [
    "STEP", "GNSS", "ACOUSTIC", "KIND_NAMES", "StepEvents", "GnssEvents", "AcousticEvents", "StandIntervals",
    "ClassTrack", "EventStream", "merge_events", "EventError",
    "EkfConfig", "EventEKF", "FilterRun", "FilterError", "run_ekf", "IMMFilter",
    "FixedNoise", "QualityNoise", "PerClassNoise", "VBAdaptiveNoise", "SageHusaNoise", "NoiseError",
    "second_moment_m2", "SmoothedTrack", "rts_smooth", "nees", "chi2_bounds", "in_bounds_share", "nis_summary",
]
