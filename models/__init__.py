"""envfuse models package (see DESIGN.md §2).

``models.fusion``: the event-driven filter core — event streams (steps, GNSS,
acoustic, standing), the EKF with heading-offset and step-scale states
(optional GNSS Gauss–Markov bias), noise policies (fixed, quality, per class,
VB-AKF, Sage–Husa), the IMM over environment classes, the RTS smoother and
NEES/NIS consistency. Pure maths on in-memory arrays; no file I/O.
"""
