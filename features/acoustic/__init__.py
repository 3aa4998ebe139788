"""The acoustic receiver: beacon chirps in a 48 kHz recording → CIR features and positions.

In the order the data flows: ``audio`` (blocks of samples), ``impulses`` (corona and
partial-discharge clicks removed before the filter), ``matched_filter``
(band-pass + matched filter, streamed), ``timing`` (beacon frames, the audio
time base of a walk), ``detection`` (per-frame detection, the receiver's main
loop), ``tracking`` (the lock of position and clock: acquire, track, confirm),
``acquisition`` (its Hough vote and clock-aided re-acquisition), ``frame_fix`` (a
frame's ranges, innovation gate and fix), ``air`` (the wind and sound-speed scale
estimated from the track), ``positions`` (Gauss–Newton TOA solution with χ² exclusion), ``cir`` (first
arrival and the nine CIR features), ``features`` (feature windows and fixes of a
whole file: :func:`~features.acoustic.features.analyse_audio`), ``uwb`` (real UWB
CIR logs, read into the same CIR code).
"""

__all__ = ["audio", "impulses", "matched_filter", "timing", "detection", "tracking", "acquisition", "frame_fix", "air",
           "positions", "cir", "features", "uwb"]
