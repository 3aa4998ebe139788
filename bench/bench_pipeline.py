"""Speed of the whole pipeline and of batch evaluation (issue 14): prints figures, asserts nothing.

1. **Raw files to fused track, one core**: a 10-minute simulated walk read
   (NMEA, audio, IMU), classified window by window and fused by ``adaptive``
   (environment classifier, per-class filter, BP network): × real time, and
   that rate divided by scipy's ``oaconvolve`` matched filter over the same
   audio timed in the same run (this VM's speed drifts 1.5–2× between days; the
   ratio is the figure to compare). Target: ≥ 500× real time (issue 14); ≥ 1,000× and ≥ 0.5 of the yardstick
   (issue 25). Then the per-stage breakdown, and the acoustic receiver's *floor*
   (:func:`_receiver_floor_child`): the seconds it spends inside compiled kernels, FFTs and numpy sorts, which
   no rewriting of the Python around them can remove while the outputs stay bit-identical, and the rate raw
   files → track would reach were that Python free.

   The readers (branch ``pipespeed``, 2026-12-02; the third walk of ``--breakdown-only``, site 5 seed 42, CPU s
   best of 5, main and branch alternated 3 rounds, load 2.6-4.5): ``read_gnss_stream`` 0.48-0.52 → 0.076-0.079
   (NMEA assembly compiled, :mod:`features.gnss.assemble`, and the stream built from the reader's columns:
   NMEA + time base 0.036-0.039, sky arrays + positions 0.015-0.016, features 0.027 unchanged); IMU read + PDR
   0.089-0.096 → 0.068-0.069 (the CSV parsed compiled); ``read_walk`` without audio 0.57-0.61 → 0.18 (its UWB
   stream, 0.045, unused by ``adaptive``, unchanged). Raw files → ``adaptive`` track, CPU, best of 3: 3.23-3.51
   s → 2.91-3.00 s (171-186× → 200-206×); every track of every method on the 3 walks identical to main's
   (``bench/track_identity.py --tol-m 0``). Before, the breakdown's "GNSS sky arrays + positions" stage read
   0.04 s only because the epochs' ``primary_satellites`` were cached by its first repeat (0.07 uncached).
   **As a user runs it** (:func:`cli_run_rate`): the figures above are of ``adaptive`` in a warm process (imports
   made, numba's kernels loaded, the walk read whole). ``envfuse run`` on the same walk, a new interpreter each time
   with ``run``'s defaults (``adaptive_blind+lag``, 300 s segments: a 10-minute walk is two cuts), is printed
   beside them, with the same walk fused whole and the interpreter's start with ``run``'s imports alone.
   Measured 2026-12-03 (this machine at load 0.7-1.2; main 3725418 and the branch ``userspeed`` alternated, best of
   2 each): main 85-90x (6.67-7.04 s wall), the branch 98-105x (5.72-6.14 s), fused whole 5.1-5.4 s both, imports
   1.6-2.0 s; in one ``--breakdown-only`` run 116x (5.17 s; whole 5.10 s; imports 1.52 s; warm ``adaptive`` 271x,
   yardstick 1,750x). What the branch changed: a segmented walk no longer fixes glibc's mmap threshold at 128 KiB
   (section 5), which had made every numpy array of 128 KiB or more a fresh mapping faulted in page by page (a
   10-minute walk in two cuts: 410,000-450,000 minor faults and 1.6-2.2 s of system time, against 52,000 and
   0.65-0.8 s). So a user's 10-minute run is a third start-up (the imports, scipy.signal and with it scipy.stats
   0.7 s of them, needed by the PDR's filters; numba's cache loads) and two thirds the receiver.
2. **Fusion step alone**: events per second of each method on that walk's
   event stream (reading excluded). Target: ≥ 50,000 steps/s for ``adaptive``.
3. **evaluate over 16 walks** (``--eval-walk-s`` each, default 60 s, simulated on the same site) with 1 and
   2 local workers: wall time, parallel efficiency T1 / (2·T2) (target ≥ 0.9), the same on a long-lived
   2-worker cluster reached as ``--scheduler`` (its second run: workers warm), the peak resident memory of a
   worker process, and the **fixed cost per run**: cluster start, a fresh worker's imports, its model load,
   the first walk's caches (its first walk minus the same walk again), the model loads per worker and
   cold-minus-warm run time; with the ``oaconvolve`` yardstick timed in the same run.

   Measured 2026-12-02 (``--evaluate-only``, 16 walks of 60 s, oaconvolve 1,795-1,856x best of 3 in the same
   runs), two runs: 1 worker 29.8-29.9 s (1.87 s/walk); a new 2-worker cluster 17.2 / 16.3 s, efficiency
   0.86 / 0.92 (two warmed-up plain processes: 0.90 / 0.94); before local workers were forked (spawned,
   one run): 0.79 (33.7 s / 21.3 s), fixed cost 2.66 s in parts, 1.49 s as new-cluster minus warm run, now
   0.13-0.19 s and 0.07-0.68 s. A long-lived cluster's warm runs: 0.87 / 0.95, one model read per worker in
   all over 3 runs. ``envfuse evaluate`` as a user runs it: 0.78 forked against 0.72-0.73 spawned (its parent
   has only read the model, so each worker still pays the first walk's caches and lazy imports).

   Where the rest went (branch ``evalspeed``, 2026-12-02; the machine shared, load 4.2-10, so wall times and
   efficiencies of that day say little and CPU seconds from /proc are the measure; ``dask_overhead`` prints them
   for Dask's pace and ``map_walks``'): Dask's periodic callbacks. The tick (every 20 ms), the system monitor
   (500 ms) and the memory monitor (100 ms) run on the event loop of the scheduler and both nannies (this
   process) and of each worker, beside its task thread: 72-111 ms of CPU per second of run outside the walks
   (3.6-7.0 s per run; on a 17 s run on a quiet machine ~1.5 s of the 34 s the two cores give), ~150-180
   wake-ups per second of each worker's event loop, and 58-109 GIL waits per second of the task threads (their
   voluntary context switches; a plain process: 1-2 per walk). At 1 s / 5 s / 1 s
   (``pipeline.parallel._LOCAL_WORKER_CONFIG``, main and branch alternated, 2 + 2 runs and 3 exploratory): 19-26
   ms/s (0.7-1.6 s per run), 6-11 GIL waits/s. Per-task machinery is not what costs: a result pickles to 0.77 MB
   in 1.5 ms; the gaps between one walk's end and the next's start on a worker add up to 0.02-0.05 s per run;
   the cluster starts in 0.16 s and closes in 0.14 s. The walks are now handed out largest first (Graham's LPT
   rule on their bytes on disk; equal-length walks here, so it changes nothing in this section, and keeps one
   long walk from being the run's tail elsewhere). ``envfuse evaluate --workers 2`` as a user runs it, CPU of all
   its processes (``cli_runs``): main 43.4 / 47.9 s, branch 41.1 / 41.2 s, ``--workers 1`` 35.9-37.4 s, 24,500 ->
   4,800 voluntary context switches. Why the user's run reads lower than this section's (0.77-0.78 against
   0.85): its fixed costs count twice in T1 / (2 T2), being paid before or beside the 8 walks of each worker
   and only once beside the 16 walks of one: its own start (imports, 1.4-1.5 s CPU), ``distributed``'s import
   (0.23-0.30 s, the 2-worker run only), and each forked worker's first walk's caches (0.6-1.0 s: numba's
   on-disk cache of 31 compiled functions rebuilt, 106 lazily imported modules: numba 72, gtsam 13; a forked
   worker of this bench's warm process has them already); and two plain processes on these two vCPUs need
   ~20 % more CPU for the same walks than one (31.5 s in one process, 38.2 s in two, load 5), which the 1-worker
   run never pays. A long-lived cluster started with Dask's defaults (what ``--scheduler`` reaches when its
   ``dask worker`` processes were started without settings) pays the profiler, the malloc threshold and the
   callbacks: a warm run of 8 walks 2.18 s of CPU outside the walks (97 ms/s; event loops 54 ms/s, 427
   wake-ups/s; 196,000 minor page faults) against 0.53 s (21 ms/s; 7 ms/s, 43 wake-ups/s; 16,000) started with
   ``map_walks``' settings, as :mod:`pipeline.parallel` tells how (``long_lived_cluster(tuned=True)``).
   This section in one run (``--evaluate-only``'s section on the same 16 walks, the test suite running beside it,
   load 3.0-10: its walls and efficiencies are not figures): Dask's pace 1.50 s in a 16.6 s run (90 ms/s) and
   2.38 s in 31.4 s (76 ms/s), GIL waits 25-67/s, the workers' event loops 391-404 wake-ups/s; ``map_walks``'
   0.64 s in 32.0 s (20 ms/s) and 0.59 s in 30.7 s (19 ms/s), 11/s, 61-63/s; ``envfuse evaluate`` CPU of all
   processes: ``--workers 1`` 33.7 s, 2 forked 40.2 s, 2 spawned 43.9 s. Wall efficiency (``evaluate`` in a warm
   process as ``evaluate_scaling`` runs it, main and branch alternated, 3 pairs, load 1.8-5.1): main 0.86 / 0.58 /
   0.52, branch 0.74 / 0.61 / 0.48, 2-worker runs of the same code moving 17-63 s from one run to the next: the
   machine gave the two workers one to two cores at random, and no wall figure of that day can show a 3-5 %
   change either way; the target (0.9) is to be read again on a quiet machine.

4. **The simulator** (issue 25 item 2, :func:`simulator_section`): a 10-minute walk on the benchmark site
   (site seed 5, walk seed 40) simulated end to end by ``simulate_walk`` (every file: gnss.nmea, imu.csv,
   truth_steps.csv, audio.wav, audio_truth.csv, uwb.csv, imu_foot.csv, truth.csv, walk.toml), each run in a
   fresh spawned process, best of 2: × real time by wall clock and by the process's CPU time (the fairer clock
   on a shared machine);
   the peak resident set of that process (VmHWM: ``ru_maxrss`` keeps the spawning process's size across the
   child's exec, and read 1,271 MiB after the evaluate section's ~1.2 GiB) beside its resident set after
   the imports; then
   stream by stream (each stream's simulation and its file writing apart, CPU s; the WAV is written block by
   block inside the audio renderer, so its writing is re-timed alone); ``oaconvolve`` over the walk's audio
   in the same run. Target ≥ 100× real time.

   Measured 2026-12-02 (branch ``simspeed2``) on this 2-core VM shared with other jobs (load average 3.3-6.9;
   the CPU time of one run moves by ±8 % with the load, so main and the branch alternated in fresh processes).
   Before: main at 6ed79dc (the ``simspeed`` merge). After: the hum and each emission's band response H(f)
   compiled (:func:`simulation.acoustic.synthesis.hum_samples`, :func:`~simulation.acoustic.synthesis.band_response`:
   exact sin/cos once per 16 samples or bins and a rounding-corrected rotation between, the dB loss by exp),
   the truth rows' band-centre absorption cached. Every file of a 600 s walk byte-identical to main's for
   (site 5, seed 40) and (site 1, seed 1); inside, the hum within 1.6e-15 of main's (unit amplitude; ≤ 3e-17 of
   full scale after its level) and H(f) within 5e-15 relative:

   - ``simulate_walk`` alone, 4 alternated rounds (site 5, seed 40): main CPU 6.53-6.98 s (median 6.74 s, 89×
     real time), branch 5.88-6.30 s (median 6.13 s, 98×), ratio 1.10;
   - this section, a quieter round (load 3.3-4.0): main CPU 6.57 s (91×; audio 5.05 s, GNSS 0.91 s), branch
     5.75 s (104×; audio 4.18 s, GNSS 1.01 s; oaconvolve 1,364× best of 3); a loaded round (load 5.8-6.9): main
     6.98 s (86×; audio 5.32), branch 6.46 s (93×; audio 4.55, GNSS 1.05; oaconvolve 556× best of 3, ratio
     0.092). Peak RSS 312-321 MiB both.

   So the 100× target is met on a quiet machine and missed by 7 % under load. What is left, per 600 s walk (CPU
   s, the branch): the ambient's Gaussian noise 0.45 (28.8 M draws from per-chunk generators; fixed by the seeds),
   corona pulses 0.35, the codec's sosfilt 0.4, per emission the tail's generator (SeedSequence, 0.2), its
   Python/numpy bookkeeping (~0.6: paths, hardware factors, Doppler, plan) and its three FFTs (chirp at its
   Doppler factor, tail, inverse: ~0.7); the GNSS's RTK engine (per-epoch Python loop with small solves, ~0.6).
   Previous round (``simspeed``, under heavier load): main before it 13.98-14.81 s, after it 7.73-7.94 s.

   Since then main (8385a81) writes two more streams, ``uwb.csv`` and ``imu_foot.csv`` (issue 26), and the same
   walk costs more: ``simulate_walk`` alone, 3 alternated rounds (load 2.5-3.4), main 8385a81 CPU 9.36-9.73 s
   (62-64×), this branch merged with it (and the corona pulses' templates added by a compiled loop) 8.59-8.84 s
   (68-70×), ratio 1.10; every one of the 9 files byte-identical to main's for (site 5, seed 40) and (site 1,
   seed 1). A cProfile of the branch: audio 5.3 s, UWB 3.4 s (``simulate_uwb``, a Python call per range:
   37,084 calls of ``_measure``), GNSS 1.4 s, foot IMU 1.1 s (profiled seconds, inflated by the profiler; the
   UWB stream is now the second cost and the next place to look for the 100× target).

   Third round (branch ``simspeed3``, 2026-12-02, machine heavily shared: load average 8.3-9.9 against 2.5-3.4
   above, so every figure reads ~20 % slower than the same code on a quiet machine). Every file of five runs
   byte-identical to main's (``cmp``): 600 s walks (site 5, seed 40) and (site 9, seed 41), a 30 s walk, a
   120 s walk with ``acoustic_air`` / ``acoustic_hardware`` / Doppler off, a 10 s-per-cell survey (142 files).
   What changed: the UWB stream (poll positions interpolated per block of rounds, the per-poll draws on Python
   floats with the quality's received total computed for all rows at once, the channel of an exact position
   computed once: a walker standing still polls it second after second, 9,602 channel computations → 3,295),
   the foot IMU (footfall phases written over index ranges instead of whole-walk masks; the dipole field
   summed over blocks of 4,096 positions: 3-4× faster, the same sums), the codec's biquads and the int16
   conversion compiled (scipy's ``sosfilt`` operations in its order), the Hatch filter compiled, smaller
   per-emission savings in the audio plan and the accumulator (``write_audio`` alone, 3 alternated rounds:
   main 4.79-4.94 s, branch 4.34-4.55 s; the GNSS writer reads ~0.05 s slower only because numba's one-time
   start, ~0.17 s, now falls in it, the first stream). ``simulate_walk`` alone, 3 alternated rounds
   (site 5, seed 40; load 8.3-8.8): main CPU 11.06-11.34 s (53-54×), branch 8.62-8.74 s (69-70×), ratio 1.29.
   This section (load 9.7-9.9): main 9.37 s (64×; audio 4.72, UWB 1.81, foot IMU 1.09, GNSS 0.99 s), branch
   7.52 s (80×; audio 4.51, UWB 0.58, foot IMU 0.60, GNSS 1.03 s); peak RSS 410 / 416 MiB. The 100× target is
   still missed: audio is 61 % of the walk, and what is left there is spread over 13,000 emissions (Python
   and small-array numpy per emission, ~70 µs, the tail's generator, three FFTs) and the ambient's 28.8 M
   Gaussian draws; the GNSS's RTK loop (small solves, LAPACK rounding) and scipy's import (~0.5 s) as before.

   Fourth round (branch ``simaudio``, 2026-12-02, load average 2.6-4.7). The audio stream's emissions are
   handled a batch of 128 at a time: the tails' generators seeded at once (numpy's SeedSequence mixing
   compiled, :func:`simulation.rng.stream_rngs`: 1.5 µs a generator instead of 13.5 µs, the same draws), each
   emission's arrival, level and Doppler factor, its band, FFT length and H(f) (one compiled pass) and the tails'
   arithmetic as arrays over the batch, and the emissions of one FFT length rendered as a group (taps scattered
   into one matrix, the spectra assembled on the band by a compiled pass, numpy's complex product kept); the
   hum's times, amplitude (numpy's ``interp`` compiled value for value) and sum fused, its harmonics loop
   vectorised by the compiler (same operations per sample); the ambient chunks' generators seeded 64 at a
   time; the IMU and foot-IMU CSV text formatted a block of rows per ``%`` (savetxt's text). Every file of
   eight cases sha256-identical to main's (229a5f6): 600 s (site 5, seed 40), 300 s (1, 1), 300 s (9, 41), 200 s
   (2, 5), 20 s (5, 40), 7 s (6, 8), 120 s with ``acoustic_air`` / ``acoustic_hardware`` / Doppler off (3, 7) and
   a survey of site 4 (25 m cells, 8 s each): 168 files. This section, main and branch alternated, two rounds
   each: main CPU 7.28 / 6.95 s (82.4× / 86.3×; audio 4.30 / 4.02 s), branch 6.21 / 5.81 s (96.6× / 103.3×,
   wall 102.5× in the quieter round; audio 3.16 / 2.98 s, IMU CSV 0.17 → 0.10 s, foot-IMU CSV 0.16 → 0.10 s);
   peak RSS 368-369 MiB main, 360-374 MiB branch. ``write_audio`` alone, alternated: main 4.29-4.45 s, branch
   3.33-3.38 s (−23 %). Two more alternated rounds on the final branch: load 3.5-3.8, main 7.04 s (85.3×),
   branch 6.41 s (93.6×); load 1.2-1.4 (quiet), main 6.70 s (89.6×; audio 3.90 s, per-stream sum 6.50 s),
   branch 5.92 s (101.4×, wall 100.7×; audio 3.11 s, per-stream sum 5.55 s = 108×), peak RSS 369 / 360 MiB.
   Over the six alternated pairs (the first two a commit or two earlier) main's median is 7.14 s (84×), the
   branch's 6.22 s (96×): ratio 1.10-1.20 pair by pair. So 100× is met on a quiet machine and missed by ~3 % under load. What is left, per
   600 s walk: the ambient's 28.8 M Gaussian draws (~0.35 s), the emissions' FFTs (13,049 emissions, 40.8 M
   samples each way, ~0.45 s), corona pulses, codec and hum (~0.15 s each), the per-emission Python left
   (paths, the tails' draws from each emission's own generator, truth rows: ~0.5 s); the UWB per-poll loop
   (0.6 s: one generator's chain of draws whose order depends on each outcome; a leaner ``_measure`` measured
   no gain and was not kept) and the GNSS's RTK loop.

   Fifth round (2026-12-03; main f5ff6ab against 0eeb718 and after, the VM slow and drifting within minutes:
   the ``oaconvolve`` yardstick read 1,553-2,407x best of 3 in this section's runs). Compiled with numba, one
   implementation each: the RTK engine's epoch loop (:func:`simulation.gnss.rtk._engine`, LAMBDA and the
   bootstrapping success rate with it; 0.84 -> 0.06 s on this walk), the UWB tag's poll rounds
   (:func:`simulation.uwb.stream._poll_rounds`, numba's Generator drawing numpy's numbers in the same order,
   stopping for Python only for a channel not computed yet; 0.93 -> 0.45 s), the steel dipoles' field
   (0.44 -> 0.18 s for the waist and foot IMUs' 300,000 positions) and the satellite sky's blocked share
   (``plan_route`` 0.20 -> 0.11 s). Every file of six walks ((5, 40) 600 s, (1, 1), (9, 41), (3, 7), (6, 8)
   300 s, (2, 5) 200 s: 54 files) and of a survey (site 3, 25 m cells, 8 s: 82 files) sha256-identical to
   main's; inside, the RTK engine's decisions (fixed, wrong, ratio) identical, positions within 3e-14 m, UWB
   ranges within 1.4e-14 m (sums in order where numpy summed pairwise or BLAS chose, ``math.dist``'s
   rounding). ``simulate_walk`` alone, steady state (best of 3 in one process), 3 alternated pairs: main
   6.62 / 6.83 / 6.42 s CPU (88-93x), this round 5.58 / 5.75 / 6.31 s (95-107x); this section, 2 alternated
   pairs: main 79.7x / 68.5x (ratio 0.0352 / 0.0424), this round 87.3x / 83.3x (0.0379 / 0.0405; per stream,
   GNSS 1.24-1.67 -> 0.60-0.67 s, foot IMU 1.03-1.04 -> 0.54-0.56 s, UWB 1.32-1.34 -> 0.97-1.10 s); an hour
   earlier, with only the RTK engine compiled, 95.0x (yardstick 2,402x). So 100x is reached in steady state on
   this VM and would be end to end on stop 34's faster day (ratio 0.040 x 2,613x = 105x), missed on a slow one. The first walk in a new process pays ~0.4 s of numba's
   cache loads (the RTK engine's 65-78 ms with LAPACK's bindings, the footprint kernel's ~0.2 s with numba's
   own start). Left: audio (~55 %, as the fourth round left it), UWB's channel (``uwb_paths`` in Python,
   ~0.25 s), the ambient's Gaussian draws.

5. **Long walks in bounded memory** (issue 25 item 3, :func:`memory_section`, ``--memory-only``): peak RSS
   (VmHWM of a fresh process) of ``envfuse run`` (default method) on a 10-minute and an 8-hour walk, both one
   simulated 300 s walk looped (``tests/long_walk.py``), and the 8-hour run's wall time and × real time
   beside ``oaconvolve``.

   Measured 2026-12-02 (``--memory-only``, machine shared, load 4-7): 10 min 297 MiB (13 s, 46x real time);
   8 h 334 MiB (465 s, 62x real time; oaconvolve best of 3 824x, ratio 0.075); 8 h / 10 min **1.126**
   (target 1.10: missed by the cut's extra length, 730 s of walk per segment against the 600 s walk fused
   whole). Before this change (main at 0285a88, the same CLI on the demo walk 201/w0 looped, VmHWM): 10.5 min
   329 MiB, 40.5 min 450 MiB, 4.0 MiB per minute of walk, so about 2.2 GiB projected for 8 hours (not run);
   this branch on the same two walks: 296 and 327 MiB. An earlier run of this section without the fixed glibc
   mmap threshold (walks/segments.py) read 303 / 367 MiB (1.21).
   With run's default segment of an hour (set after the merge: seams cost accuracy), ``--memory-only --long-h
   1.1`` on a quiet machine: 10 min 282 MiB (120x real time), 66 min (two segments, the first cut 3,610 s)
   479 MiB (116x; oaconvolve best of 3 1,829x, ratio 0.063): ratio 1.70. Any longer walk is bounded by the same
   one-hour cut; ``--segment-s 600`` gives the 1.126 above.
   With the filters and readers resumed across the seams (branch seams; run's default segment then 300 s, so
   a 10-minute walk is two segments and every cut at most 430 s), ``--memory-only --segment-s 300`` on a
   machine at load 5-7: 10 min 338 MiB, 8 h 341 MiB (1,919 s wall, 15x real time; oaconvolve best of 3 301x,
   ratio 0.050): 8 h / 10 min **1.009**; ``--long-h 2`` in an earlier run: 350 / 341 MiB (0.975; its 10-minute
   process compiled the changed numba core).
   Without the fixed mmap threshold (branch ``userspeed``, 2026-12-03: ``envfuse run`` with its defaults on the
   bench's 600 s walk of seed 42 looped, /usr/bin/time, load 0.1-1.2): 10 min 291.6-292.6 MiB, 4 h 294.5-294.8,
   8 h 293.2 MiB: 8 h / 10 min **1.002-1.006**; with the threshold fixed 286.9 / 288.7 MiB (4 h). Time: 4 h
   83-99 s wall (2.9-5.0 s system, 54,000 minor faults) against 119-135 s (32-34 s system, 10.7-11.2 M faults);
   8 h 162 s wall, **178x** real time. The fix had been measured on a 40-minute walk's later segments (365 vs 327
   MiB) when the cuts held 120 s of warm-up and 600 s segments; today's cuts are 331 s. The same runs found a
   long walk across midnight (UTC) cut wrongly: the NMEA cutter counted the midnight twice, every epoch after it
   went a day late, the cuts after midnight held no NMEA (fused without GNSS) and the last one all of it (2.3 h of
   NMEA read by one cut: a 4-hour walk from 22:20 UTC peaked at 725 MiB). Fixed; ``tests/test_long_walks.py`` has
   a walk from 23:59 UTC. This section's walk (seed 90) starts at 01:09 UTC and never crossed midnight.
   This section after both (``--memory-only``, 2026-12-03, load ~1): 10 min 286 MiB (86x real time), 8 h 290 MiB
   in 148 s wall, **195x** real time (oaconvolve best of 3 1,979x, ratio 0.099): 8 h / 10 min **1.014**.

**Issue 25 at its close** (2026-12-03, this VM at load 0.4-1.6). Every section in one run of this script (15 min
9 s wall; no flags): raw files -> ``adaptive`` track on w7 (walk seed 47) 462x real time, ratio 0.192 to
``oaconvolve``'s best of 3 (2,404x); ``envfuse run`` as a user runs it 134x (4.49 s, of which 1.53 s the
interpreter and imports); the receiver 522x (80 % of the stages' 1.44 s); its floor, were every line of Python
around its kernels, FFTs and sorts free, 863x. ``evaluate`` over 16 walks: 31.0 s on 1 worker, 17.9 s on 2
(0.87; plain processes 1.02), a long-lived cluster with ``map_walks``' settings 0.98, fixed cost of a new
cluster -0.07 s. Simulator 71.3x wall in that run (CPU 72.3x, ratio 0.0391 to a yardstick of 1,822x);
``--simulator-only`` half an hour earlier 95.3x (CPU 97.1x, ratio 0.0384, yardstick 2,485x). Memory: 10 min
278 MiB, 8 h 281 MiB (1.010), the 8-hour walk in 189 s (152x).
Against the code at the issue's start (d35dfd1, in a worktree beside main, the same machine, alternated): the
receiver alone on the bench's walk (site 5, seed 42, 600 s; its site without the UWB anchors the old reader
refuses; the two receivers' fixes differ, the detector having changed since) 5.39 / 5.03 / 4.98 s CPU
(111-120x) -> 1.43 / 1.38 / 1.37 s (418-437x); ``simulate_walk`` of a 600 s walk (site 5, seed 40, fresh process,
imports excluded) 27.8 / 25.1 s CPU (22-24x; GNSS, IMU, audio) -> 5.92 / 6.14 s (98-101x; UWB and foot IMU
besides).
``envfuse benchmark --split standard --workers 2`` from an empty folder: its 11 sites' surveys and 33 walks
simulated in 111 s (400 s at the issue's start), the whole benchmark (libraries, models, evaluation) in 6 min
56 s. So memory is met; the simulator's 100x on a quiet machine (95-101x) and not under load (its ratio to the
yardstick holds at 0.038-0.039); ``evaluate``'s 0.9 is at its edge (0.87 here, 0.86-0.93 in earlier runs, plain
processes 1.02); the 1,000x of raw files -> track, and 0.5 of the yardstick, are not. The floor says why: with today's algorithms the receiver's compiled kernels, FFTs and
sorts alone, plus the other stages, leave at most 581-863x (the walk decides: how often it loses lock and
re-acquires); reaching 1,000x needs less work, not less Python (an acquisition that does not vote over the
site at every lost lock, fewer FFTs per frame), each such change judged on the fixes of held-out walks.

**Issue 25, a run on 2026-12-03 evening** (every section, no flags, 16 min wall; this VM slower that evening: the
yardstick's best of 3 1,981x in section 1 against 2,404x at the close above, 1,196x in section 4): raw files ->
``adaptive`` on w7 298x (ratio 0.150); its stages 1.654 s CPU (363x, ratio 0.183), the receiver 1.347 s of it
(445x, 81 %); the floor 0.403 s of the receiver's 1.131 s inside kernels, FFTs and sorts: at most 845x. ``envfuse
run`` as a user runs it 144x (4.17 s, the interpreter and imports 1.24 s) against 134x (4.49 s, 1.53 s) at the
close: :func:`user_env` (this VM sets ``PYTHONDONTWRITEBYTECODE``, so every child had compiled envfuse from
source). ``evaluate`` over 16 walks: 34.1 s on 1 worker, 18.8 s on 2 (0.91); as a user runs it 0.96 (forked
workers); a long-lived cluster with ``map_walks``' settings 0.89 warm, with Dask's defaults 0.82; fixed cost 0.46 s.
Simulator 66.4x wall (CPU 67.5x; ratio 0.0555 to that section's slower yardstick, against 0.038-0.042 at the
close and 0.0416 this morning at 94.8x: the machine, not the code). Memory: 10 min 277 MiB, 8 h 281 MiB (1.013),
the 8-hour walk in 195 s (148x). ``run``'s default became ``kf_quality+lag`` after this run (README, "What the
benchmark shows"); section 1 still measures ``adaptive`` (the heavier filter, comparable with the figures above).

Usage: ``python bench/bench_pipeline.py [--quick] [--evaluate-only | --simulator-only | --memory-only]``
(``--quick``: 2-minute walks, 4 walks; ``--evaluate-only``: 2 training walks of 120 s, then section 3 only;
``--simulator-only``: section 4 only, with ``--quick`` on a 120 s walk; ``--memory-only``: 2 training walks of
120 s, then section 5 only).
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.signal
import soundfile as sf

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def oaconvolve_rate(wav: Path) -> tuple[float, float]:
    """× real time of scipy's oaconvolve with the receiver's 10 ms chirp kernel over the whole file: the first
    run (the figure earlier notes quote; it also allocates and faults in its 115 MB output, and read 154–377×
    on one day) and the best of three (that memory reused: 1,900× on the same day)."""
    from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank

    x, fs = sf.read(str(wav), dtype="float32")
    h = MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], fs).kernels[0].astype(np.float32)
    walls = []
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        walls.append(time.perf_counter() - t0)
    duration = len(x) / fs
    return duration / walls[0], duration / min(walls)


def build(tmp: Path, walk_s: float, n_walks: int):
    from features.site import save_site
    from models.bp import BPConfig
    from models.fusion.model import save_fusion_model
    from models.environment import EnvironmentClassifier
    from training.filters import train_fusion
    from walks.inputs import window_features
    from walks.reader import read_walk
    from simulation.site.layout import generate_site
    from simulation.walk import simulate_walk

    site = tmp / "site"
    site.mkdir()
    save_site(generate_site(5), site / "site.toml")
    walks = [simulate_walk(site, tmp / f"w{k}", seed=40 + k, duration_s=walk_s) for k in range(n_walks)]
    train = walks[:2]
    X, y = [], []
    for w in train:
        d = read_walk(w)
        t, Xw = window_features(d)
        X.append(Xw)
        y.append(d.truth.class_at(t - 1.0))
    clf = EnvironmentClassifier(min_samples=10).fit(np.vstack(X), np.concatenate(y))
    model = train_fusion(train, clf, bp_config=BPConfig(n_members=5))
    save_fusion_model(model, tmp / "model")
    return walks, tmp / "model"


def pipeline_rate(walk: Path, model_dir: Path) -> tuple[float, float, dict]:
    from models.fusion.model import load_fusion_model
    from walks.inputs import walk_inputs
    from walks.methods import method, method_names, run_methods
    from walks.reader import read_walk

    model = load_fusion_model(model_dir)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        data = read_walk(walk)
        inputs = walk_inputs(data, model.classifier, model.temporal, "forward")    # as run feeds the filters
        tracks, _ = run_methods(model, inputs, ("adaptive",), smooth=False)
        best = min(best, time.perf_counter() - t0)
    duration = float(data.walk.duration_s)
    rates = {}
    n_events = len(inputs.events)
    r = data.pdr.result
    n_steps = int(np.sum(np.isfinite(r.heading_rad) & np.isfinite(r.step_length_m)))     # heel strikes
    for m in [n for n in method_names() if method(n).filter or n.startswith("adaptive")]:
        wall = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            _, skipped = run_methods(model, inputs, (m,), smooth=False)
            wall = min(wall, time.perf_counter() - t0)
        # a method that cannot run on this walk (kf_map without a site map) returns at once: say so, not a rate
        rates[m] = skipped[m] if m in skipped else n_events / wall
    return duration / best, (n_events, n_steps), rates


def user_env() -> dict:
    """The environment of a ``envfuse`` process started as a user starts it: this one's, the repository on
    ``PYTHONPATH``, without ``PYTHONDONTWRITEBYTECODE``, and the repository's modules compiled to bytecode first
    (``compileall``, as ``pip install`` does for an installed package and a first run does for a clone).

    This VM sets ``PYTHONDONTWRITEBYTECODE=1``: a child of a fresh clone then compiled every one of envfuse's
    modules from source at each start (2026-12-03, ``envfuse run`` on a 10-minute walk: its imports 1.56 s
    against 1.29-1.33 s with the bytecode cached; the run 5.9-6.1 s against 5.4-5.7 s, the test suite running
    beside it), a cost no user with a writable ``__pycache__`` pays after the first run."""
    import subprocess

    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    packages = [str(ROOT / d) for d in ("features", "fingerprints", "models", "pipeline", "simulation", "training",
                                         "walks") if (ROOT / d).is_dir()]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *packages], env=env, check=True,
                   stdout=subprocess.DEVNULL)
    return env


def cli_run_rate(walk: Path, model_dir: Path, duration_s: float, repeat: int = 3) -> dict:
    """``envfuse run`` on ``walk`` as a user runs it: a fresh interpreter each time, the default method and segment
    length (``run``'s defaults), the track written; beside it the same walk fused whole (``--segment-s`` past its
    length: one read, no cuts) and the interpreter's start with the imports ``run`` makes, alone. Best of
    ``repeat`` of each, alternated; wall and CPU (user + system, of the child) seconds."""
    import resource
    import subprocess

    env = user_env()
    out = walk.parent / "cli_run.csv"
    base = [sys.executable, "-m", "pipeline.cli", "run", str(walk), "--model", str(model_dir), "--out", str(out),
            "--force"]
    cases = {"default": base, "whole": base + ["--segment-s", f"{max(duration_s + 60.0, 600.0):g}"],
             "imports": [sys.executable, "-c", "import pipeline.cli, pipeline.commands.fuse, pipeline.evaluate, "
                                               "walks.fuse, walks.segments"]}
    best = {k: (math.inf, math.inf) for k in cases}
    for _ in range(repeat):
        for name, cmd in cases.items():
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            wall = time.perf_counter() - t0
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
            best[name] = min(best[name], (wall, cpu))
    return best


def stage_breakdown(walk: Path, model_dir: Path, repeat: int = 5) -> dict:
    """CPU seconds (best of ``repeat``, process time) of each stage of raw files -> adaptive track.

    The stages :func:`walks.reader.read_walk` and the fusion run one after another:
    NMEA reading (and the walk's time base), GNSS sky arrays and positions (ENU, sigma), GNSS
    features, the acoustic receiver, IMU reading and PDR, the fusion inputs from the read walk
    (events, the 14 window features, the classifier) and the ``adaptive`` filter.
    """
    from features.gnss.features import gnss_features, sky_arrays
    from features.gnss.nmea import epochs_on_time_base, read_nmea_columns
    from features.gnss.positions import fixes_to_enu
    from features.walk import load_walk
    from models.fusion.model import load_fusion_model
    from walks import reader as wd
    from walks.inputs import walk_inputs
    from walks.methods import run_methods

    model = load_fusion_model(model_dir)
    info = load_walk(walk)
    site = info.load_site()
    o = site.origin
    state: dict = {}

    def nmea():     # as walks.reader.read_gnss_stream reads it: the reader's columns
        state["epochs"] = epochs_on_time_base(read_nmea_columns(info.path("gnss"))[0], info.start_utc)

    def gnss_positions():
        state["sky"] = sky_arrays(state["epochs"])
        fixes_to_enu(state["epochs"], o.lat_deg, o.lon_deg, o.alt_m, sky=state["sky"])

    def gnss_feats():
        gnss_features(state["sky"])

    def audio():
        wd.read_acoustic_stream(info, site, None)

    def imu():
        wd.read_pdr_stream(info, (0.0, 0.0), None)

    state["data"] = wd.read_walk(walk)

    def inputs():
        state["inputs"] = walk_inputs(state["data"], model.classifier)

    def fusion():
        run_methods(model, state["inputs"], ("adaptive",), smooth=False)

    stages = {"NMEA read + time base": nmea, "GNSS sky arrays + positions": gnss_positions,
              "GNSS features": gnss_feats, "acoustic receiver": audio, "IMU read + PDR": imu,
              "fusion inputs (events, windows, classifier)": inputs, "adaptive filter": fusion}
    out = {}
    for name, fn in stages.items():
        best = np.inf
        for _ in range(repeat):
            gc.collect()  # each stage starts from a collected heap (the build left much garbage behind)
            t0 = time.process_time()
            fn()
            best = min(best, time.process_time() - t0)
        out[name] = best
    return out


def _receiver_floor_child(walk: str, repeat: int = 5) -> dict:
    """In a spawned interpreter (its wrappers must not leak into the other sections): the acoustic receiver on
    ``walk`` (best of ``repeat`` by wall time) with every compiled kernel of :mod:`features.acoustic` (numba), the
    FFTs (``scipy.fft``) and numpy's sorts and partitions wrapped by a timer: the seconds spent inside them, a
    floor no rewriting of the Python around them can go below while the outputs stay the same (the matched
    filter's complex products and magnitudes, vectorised numpy too, are not counted: the floor is an
    underestimate). The timer costs ~0.2 µs a call, ~30,000 calls a walk."""
    import functools
    import importlib
    import pkgutil

    import numba
    import scipy.fft

    import features.acoustic as fa
    from features.walk import load_walk
    from walks import reader as wd

    inside: dict = {}

    def timed(name, f):
        @functools.wraps(f)
        def g(*a, **k):
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                inside[name] = inside.get(name, 0.0) + time.perf_counter() - t0
        return g

    for m in pkgutil.iter_modules(fa.__path__):
        mod = importlib.import_module(f"features.acoustic.{m.name}")
        for name, obj in list(vars(mod).items()):
            if isinstance(obj, numba.core.registry.CPUDispatcher):
                setattr(mod, name, timed(name, obj))
    for name in ("rfft", "ifft", "irfft", "fft"):
        setattr(scipy.fft, name, timed(f"scipy.fft.{name}", getattr(scipy.fft, name)))
    for name in ("sort", "argsort", "partition"):
        setattr(np, name, timed(f"np.{name}", getattr(np, name)))
    info = load_walk(walk)
    site = info.load_site()
    wd.read_acoustic_stream(info, site, None)
    best = None
    for _ in range(repeat):
        inside.clear()
        t0 = time.perf_counter()
        wd.read_acoustic_stream(info, site, None)
        wall = time.perf_counter() - t0
        if best is None or wall < best[0]:
            best = (wall, dict(inside))
    return {"wall_s": best[0], "inside": best[1]}


def receiver_floor(walk: Path) -> dict:
    """:func:`_receiver_floor_child` in a spawned interpreter."""
    import multiprocessing
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(_receiver_floor_child, (str(walk),))


def _peak_rss_task(walk, model_dir, methods, force):
    """:func:`pipeline.evaluate.evaluate_walk`, plus this process's peak resident memory (VmHWM, MiB).

    VmHWM is the high-water mark of this process's own address space since it started; getrusage's
    maxrss of children would also count the parent's pages at the fork before the worker's exec
    (Linux keeps the larger), which put every worker at the size of this bench process (~1 GiB).
    """
    from pipeline.evaluate import evaluate_walk

    evaluate_walk(walk, model_dir, methods, force)
    return _vm_hwm_mib()


def evaluate_scaling(walks, model_dir: Path, tmp: Path, repeat: int = 2) -> dict:
    """Wall time of ``evaluate`` with 1 and 2 local workers, the runs interleaved (1, 2, 1, 2, ...) and the
    best of ``repeat`` kept: this VM's speed moves by tens of per cent within minutes, and interleaving
    lets both see the same machine. Each 2-worker run starts its own Dask cluster (worker start-up and
    imports included, as a user's ``envfuse evaluate --workers 2`` pays them). The 1-worker run is a loop in
    this process, already warm (imports made, model read, caches filled)."""
    from pipeline.evaluate import evaluate

    out: dict = {1: np.inf, 2: np.inf}
    for _ in range(repeat):
        for workers in (1, 2):
            t0 = time.perf_counter()
            evaluate(walks, model_dir, tmp / f"rep{workers}", workers=workers, progress=False, plots=False)
            out[workers] = min(out[workers], time.perf_counter() - t0)
    return out


def long_lived_cluster(walks, model_dir: Path, tmp: Path, runs: int = 3, tuned: bool = False) -> dict:
    """``evaluate --scheduler`` on one 2-worker ``LocalCluster`` kept across ``runs`` runs (as a long-lived
    cluster would be; its workers spawned, as ``dask worker`` processes are): each run's wall time, the model
    loads each worker has made after it (one per worker in all when the workers keep their model across walks
    and runs), and the peak resident memory of a worker (VmHWM; a spawned worker shares no pages with this
    process, which a forked one would count). With Dask's defaults, as a ``dask worker`` started without
    settings runs; ``tuned``: with the local cluster's settings but the start method
    (``pipeline.parallel._LOCAL_WORKER_CONFIG``, as :mod:`pipeline.parallel`'s docstring tells a user to start one)."""
    import logging

    import dask
    from distributed import Client, LocalCluster

    from pipeline.evaluate import evaluate, model_loads
    from pipeline.parallel import _LOCAL_WORKER_CONFIG

    settings = {k: v for k, v in _LOCAL_WORKER_CONFIG.items() if "multiprocessing-method" not in k} if tuned else {}
    t0 = time.perf_counter()
    with dask.config.set(settings), LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                 dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        client.wait_for_workers(2)
        start = time.perf_counter() - t0
        walls, loads = [], []
        for k in range(runs):
            t0 = time.perf_counter()
            evaluate(walks, model_dir, tmp / f"sched{k}", scheduler=cluster.scheduler_address, progress=False,
                     plots=False)
            walls.append(time.perf_counter() - t0)
            loads.append(sorted(client.run(model_loads).values()))
        from walks.methods import method_names

        rss = client.gather(client.map(_peak_rss_task, [str(w) for w in walks], model_dir=str(model_dir),
                                       methods=method_names(), force=False, pure=False))
    return {"start_s": start, "walls": walls, "loads": loads, "rss_mib": max(rss)}


def _cold_probe(walk, model_dir) -> dict:
    """On a fresh worker: seconds to import what a task needs, to read the model, to run the first walk and
    the same walk again (the difference: the first walk's caches: numba's on-disk cache, lazy imports), and
    how many times the worker read the model meanwhile."""
    import sys

    t0 = time.perf_counter()
    before = len(sys.modules)
    from pipeline.evaluate import evaluate_walk, load_model
    from walks.methods import method_names
    import pipeline.site_map  # noqa: F401 - what evaluate_walk imports on its first call
    import walks.fuse  # noqa: F401

    from pipeline.evaluate import model_loads

    loads = model_loads()            # a forked worker inherits this process's count; what it adds is its own
    t1 = time.perf_counter()
    load_model(model_dir)
    t2 = time.perf_counter()
    evaluate_walk(walk, model_dir, method_names(), False)
    t3 = time.perf_counter()
    evaluate_walk(walk, model_dir, method_names(), False)
    t4 = time.perf_counter()
    return {"imports_s": t1 - t0, "modules": len(sys.modules) - before, "load_s": t2 - t1,
            "first_s": t3 - t2, "again_s": t4 - t3, "loads": model_loads() - loads}


def fresh_imports_s(repeat: int = 3) -> float:
    """Seconds a new interpreter takes to import what a walk's task needs (best of ``repeat``): a spawned
    worker pays them before its first walk (the bench's own workers also import this script, so the probe on
    them under-counts)."""
    import subprocess

    code = ("import time; t = time.perf_counter(); import distributed.worker, pipeline.evaluate, walks.fuse, "
            "pipeline.site_map; print(time.perf_counter() - t)")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return min(float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                                    check=True).stdout) for _ in range(repeat))


def cli_runs(walks, model_dir: Path, tmp: Path) -> dict:
    """``envfuse evaluate --workers N --no-plots`` on the walks as a user runs it (a new process: its imports,
    the model read, for N = 2 the local cluster): wall seconds for N = 1, N = 2 (workers forked on Linux) and
    N = 2 with the workers spawned (Dask's default, what evaluate did before), one run each; and the CPU seconds
    of each run, its process and every process it started (``RUSAGE_CHILDREN``: a worker is counted once its
    parent has reaped it): what N = 2 spends beyond N = 1, however busy the machine."""
    import resource
    import subprocess

    env = user_env()
    out, cpu = {}, {}
    for name, n, extra in ((1, 1, {}), (2, 2, {}), ("2 spawned", 2,
                                                   {"DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD": "spawn"})):
        r0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
        subprocess.run([sys.executable, "-m", "pipeline", "evaluate", *map(str, walks), "--model", str(model_dir),
                        "--report", str(tmp / f"cli{n}"), "--workers", str(n), "--no-plots"], env={**env, **extra},
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        out[name], r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu[name] = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return {**out, "cpu": cpu}


def fixed_cost(walk, model_dir: Path) -> dict:
    """The parts of a run's fixed cost on a fresh 2-worker cluster, as ``evaluate --workers 2`` starts it:
    the cluster's start (until both workers answer), then per worker :func:`_cold_probe` (worst worker), and
    a new interpreter's imports (:func:`fresh_imports_s`). With forked workers (Linux) the probe's imports and
    model load are what the fork did not already give, from this process, which has run walks: warmer than
    ``envfuse evaluate``'s, which has only read the model (:func:`cli_runs` times that)."""
    import logging

    import dask
    from distributed import Client, LocalCluster

    from pipeline.parallel import local_worker_config

    t0 = time.perf_counter()
    with dask.config.set(local_worker_config()):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    with cluster, Client(cluster) as client:
        client.wait_for_workers(2)
        start = time.perf_counter() - t0
        workers = list(client.scheduler_info()["workers"])
        probes = client.gather([client.submit(_cold_probe, str(walk), str(model_dir), workers=[w], pure=False)
                                for w in workers])
    worst = {k: max(p[k] for p in probes) for k in probes[0]}
    return {"start_s": start, **worst, "fresh_imports_s": fresh_imports_s()}


def machine_ceiling(walks, model_dir: Path) -> float:
    """Parallel efficiency of the same per-walk work in two pre-started, warmed-up plain processes (no
    Dask, imports and the first walk excluded, each taking half the walks): what these two cores give."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    times = {}
    for n in (1, 2):
        with ctx.Manager() as m:
            barrier = m.Barrier(n)
            with ctx.Pool(n) as pool:
                walls = pool.map(_ceiling_worker, [(list(map(str, walks[i::n])), str(model_dir), barrier)
                                                   for i in range(n)])
        times[n] = max(walls)
    return times[1] / (2 * times[2])


def _ceiling_worker(args) -> float:
    walks, model_dir, barrier = args
    from pipeline.evaluate import evaluate_walk
    from walks.methods import method_names

    evaluate_walk(walks[0], model_dir, method_names(), False)      # warm: imports, caches
    barrier.wait()
    t0 = time.perf_counter()
    for w in walks:
        evaluate_walk(w, model_dir, method_names(), False)
    return time.perf_counter() - t0


_DASK_PACE = {"distributed.admin.tick.interval": "20ms", "distributed.admin.system-monitor.interval": "500ms",
              "distributed.worker.memory.monitor-interval": "100ms"}
"""Dask's own pace for the periodic callbacks ``map_walks`` slows (``pipeline.parallel._LOCAL_WORKER_CONFIG``)."""


def _overhead_task(walk, model_dir, methods) -> dict:
    """:func:`pipeline.evaluate.evaluate_walk` on a worker, with its own CPU (this thread's) and voluntary context
    switches (each one a wait, mostly for the GIL), then the worker's whole CPU so far and its event loop's
    (the main thread of a Dask worker process), read from /proc."""
    import resource
    import threading

    from pipeline.evaluate import evaluate_walk

    r0, t0 = resource.getrusage(resource.RUSAGE_THREAD), time.thread_time()
    evaluate_walk(walk, model_dir, methods, False)
    task_cpu, r1 = time.thread_time() - t0, resource.getrusage(resource.RUSAGE_THREAD)
    loop = threading.main_thread().native_id
    with open(f"/proc/self/task/{loop}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    with open(f"/proc/self/task/{loop}/status") as f:
        loop_vcs = next(int(line.split()[1]) for line in f if line.startswith("voluntary_ctxt_switches"))
    return {"pid": os.getpid(), "task_cpu": task_cpu, "task_vcs": r1.ru_nvcsw - r0.ru_nvcsw,
            "process_cpu": time.process_time(),       # a forked worker's clock starts at its fork
            "loop_cpu": (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"), "loop_vcs": loop_vcs}


def dask_overhead(walks, model_dir: Path, rounds: int = 2) -> dict:
    """CPU a 2-worker run spends outside its tasks, with Dask's pace of periodic callbacks (set as a user would,
    through ``DASK_...`` variables, which ``map_walks`` leaves standing) and with ``map_walks``' own, alternated
    ``rounds`` times: this process's CPU over the run (scheduler, nannies, client, the cluster's start and stop)
    plus each worker's up to its last walk, minus the walks' own thread CPU. Counted in CPU seconds, it does not
    depend on how busy the machine is the way wall time does (only through the run's length: the callbacks come
    per second); also per second of run, the workers' event loops' CPU and wake-ups, and the task threads'
    voluntary context switches per second."""
    import dask

    from pipeline.parallel import _dask_env_name, map_walks
    from walks.methods import method_names

    out: dict = {"dask": [], "envfuse": []}
    for _ in range(rounds):
        for pace in out:
            names = [_dask_env_name(k) for k in _DASK_PACE] if pace == "dask" else []
            for name, value in zip(names, _DASK_PACE.values()):
                os.environ[name] = value
            dask.config.refresh()
            try:
                c0, w0 = time.process_time(), time.perf_counter()
                res = map_walks(_overhead_task, [str(w) for w in walks], str(model_dir), method_names(), workers=2,
                                progress=False)
                main_cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            finally:
                for name in names:
                    del os.environ[name]
                dask.config.refresh()
            last = {r["pid"]: r for r in sorted(res, key=lambda r: r["process_cpu"])}     # each worker's last walk
            task_cpu = sum(r["task_cpu"] for r in res)
            out[pace].append({"wall_s": wall, "overhead_s": main_cpu + sum(r["process_cpu"] for r in last.values())
                              - task_cpu, "main_s": main_cpu, "task_s": task_cpu,
                              "loop_ms_per_s": 1e3 * sum(r["loop_cpu"] for r in last.values()) / wall,
                              "loop_wakeups_per_s": sum(r["loop_vcs"] for r in last.values()) / wall,
                              "task_waits_per_s": sum(r["task_vcs"] for r in res) / wall,
                              "load": os.getloadavg()[0]})
    return out


def build_eval_walks(tmp: Path, walk_s: float, n: int = 16) -> list[Path]:
    """``n`` more walks of ``walk_s`` seconds on the site :func:`build` drew (seeds 100...)."""
    from simulation.walk import simulate_walk

    return [simulate_walk(tmp / "site", tmp / f"e{k}", seed=100 + k, duration_s=walk_s, progress=False)
            for k in range(n)]


def evaluate_section(walks, model_dir: Path, tmp: Path, walk_s: float) -> None:
    """Section 3: evaluate over the walks on 1 and 2 workers, a long-lived cluster, the fixed cost per run."""
    n = len(walks)
    yard, yard_warm = oaconvolve_rate(walks[0] / "audio.wav")
    times = evaluate_scaling(walks, model_dir, tmp)
    eff = times[1] / (2 * times[2])
    lived = long_lived_cluster(walks, model_dir, tmp)
    warm = min(lived["walls"][1:])
    tuned = long_lived_cluster(walks, model_dir, tmp, tuned=True)
    fc = fixed_cost(walks[0], model_dir)
    cli = cli_runs(walks, model_dir, tmp)
    ceiling = machine_ceiling(walks, model_dir)
    over = dask_overhead(walks, model_dir)
    print(f"yardstick in this run: oaconvolve over one {walk_s:.0f} s walk's audio, first run {yard:,.0f}x, "
          f"best of 3 {yard_warm:,.0f}x real time")
    print(f"evaluate {n} walks of {walk_s:.0f} s, every method (best of 2, interleaved): 1 worker (this process, "
          f"warm) {times[1]:.1f} s = {times[1] / n:.2f} s/walk; 2 workers (a new local cluster per run) "
          f"{times[2]:.1f} s: parallel efficiency {eff:.2f} (target 0.9); the same work in two warmed-up plain "
          f"processes: {ceiling:.2f}")
    for pace, label in (("dask", "Dask's pace (tick 20 ms, system monitor 500 ms, memory monitor 100 ms)"),
                        ("envfuse", "map_walks' pace (1 s, 5 s, 1 s)")):
        runs = over[pace]
        print(f"CPU outside the walks of a 2-worker run, {label}: "
              + "; ".join(f"{r['overhead_s']:.2f} s in a {r['wall_s']:.1f} s run "
                          f"({1e3 * r['overhead_s'] / r['wall_s']:.0f} ms/s; this process {r['main_s']:.2f} s, worker "
                          f"event loops {r['loop_ms_per_s']:.1f} ms/s, {r['loop_wakeups_per_s']:.0f} wake-ups/s; task "
                          f"threads' GIL waits {r['task_waits_per_s']:.0f}/s; load {r['load']:.1f})" for r in runs))
    print(f"as a user runs it (envfuse evaluate --no-plots, a new process each): --workers 1 {cli[1]:.1f} s, "
          f"--workers 2 {cli[2]:.1f} s: efficiency {cli[1] / (2 * cli[2]):.2f}; --workers 2 with spawned "
          f"workers (as before) {cli['2 spawned']:.1f} s: {cli[1] / (2 * cli['2 spawned']):.2f}; CPU of all their "
          f"processes {cli['cpu'][1]:.1f} / {cli['cpu'][2]:.1f} / {cli['cpu']['2 spawned']:.1f} s (2 workers - 1: "
          f"{cli['cpu'][2] - cli['cpu'][1]:+.2f} s forked, {cli['cpu']['2 spawned'] - cli['cpu'][1]:+.2f} s spawned)")
    print(f"long-lived 2-worker cluster (evaluate --scheduler), started in {lived['start_s']:.1f} s: runs "
          + ", ".join(f"{w:.1f} s" for w in lived["walls"])
          + f"; efficiency of a warm run {times[1] / (2 * warm):.2f}; model loads per worker after each run "
          + ", ".join(str(x) for x in lived["loads"]) + f"; peak RSS of a worker {lived['rss_mib']:.0f} MiB")
    print(f"the same started with map_walks' settings (profiler off, malloc's threshold left alone, callbacks at 1 s / "
          f"5 s / 1 s; its workers spawned): runs " + ", ".join(f"{w:.1f} s" for w in tuned["walls"])
          + f"; efficiency of a warm run {times[1] / (2 * min(tuned['walls'][1:])):.2f}; peak RSS of a worker "
          f"{tuned['rss_mib']:.0f} MiB")
    first = fc["first_s"] - fc["again_s"]
    print(f"fixed cost of a run on a new 2-worker cluster (as evaluate --workers 2 starts it): cluster start "
          f"{fc['start_s']:.2f} s; on a worker, imports {fc['imports_s']:.2f} s ({fc['modules']} modules; a new "
          f"interpreter's: {fc['fresh_imports_s']:.2f} s), model load {fc['load_s'] * 1e3:.1f} ms, first walk's "
          f"caches {first:.2f} s (first walk {fc['first_s']:.2f} s, again {fc['again_s']:.2f} s): "
          f"{fc['start_s'] + fc['imports_s'] + fc['load_s'] + first:.2f} s in all; model reads on a worker over "
          f"its first two walks {fc['loads']} (the run's own check in this process: 1); "
          f"new-cluster run minus warm run: {times[2] - warm:.2f} s")


# -- long walks in bounded memory (issue 25 item 3) --------------------------------------------------------------


def memory_section(tmp: Path, model_dir: Path, base_s: float = 300.0, long_h: float = 8.0,
                   segment_s: float | None = None, method: str | None = None) -> None:
    """Peak memory of ``envfuse run`` (default method, or ``method``: e.g. a ``+rts`` track, smoothed over the whole
    walk from per-segment files, walks/segment_rts.py, whose peak size is also printed) on a 10-minute and an
    ``long_h``-hour walk, each in a fresh process (its VmHWM), and the long run's wall time and × real time beside
    the ``oaconvolve`` yardstick over the base walk's audio. Both walks are one simulated walk of ``base_s`` looped
    (``tests/long_walk.py``: timestamps continued, audio appended block by block), so they differ in length
    only. Target: the two peaks within 10 %. ``segment_s``: run's ``--segment-s`` (None: its default)."""
    from simulation.walk import simulate_walk
    from tests.long_walk import loop_walk, peak_rss_mib

    base = simulate_walk(tmp / "site", tmp / "mem_base", seed=90, duration_s=base_s)
    yard, yard_warm = oaconvolve_rate(base / "audio.wav")
    lengths = {"10 min": round(600.0 / base_s), f"{long_h:g} h": round(long_h * 3600.0 / base_s)}
    peaks = {}
    for label, loops in lengths.items():
        t0 = time.perf_counter()
        walk = loop_walk(base, tmp / f"mem_{loops}", loops)
        made = time.perf_counter() - t0
        t0 = time.perf_counter()
        seg = [] if segment_s is None else ["--segment-s", f"{segment_s:g}"]
        seg += [] if method is None else ["--method", method]
        watch = _TempWatch(tmp) if method is not None and method.endswith("+rts") else None
        peaks[label] = peak_rss_mib(["run", str(walk), "--model", str(model_dir), "--out", str(tmp / f"{loops}.csv")]
                                    + seg)
        wall = time.perf_counter() - t0
        dur = loops * base_s
        if watch is not None:
            print(f"  {method}: the whole walk's smoother's temporary files reached {watch.stop() / 2**20:,.0f} MiB")
        name = "" if method is None else " --method " + method
        print(f"envfuse run{name}, {label} walk ({loops} x {base_s:.0f} s, written in {made:.0f} s): peak RSS "
              f"{peaks[label]:.0f} MiB, {wall:.0f} s wall, {dur / wall:,.0f}x real time (oaconvolve in the same run: "
              f"first {yard:,.0f}x, best of 3 {yard_warm:,.0f}x; ratio {dur / wall / yard_warm:.3f})", flush=True)
        for f in walk.iterdir():
            f.unlink()
    a, b = peaks.values()
    print(f"peak memory {long_h:g} h / 10 min: {b / a:.3f} (target within 10 %)")


class _TempWatch:
    """The largest total size of ``run``'s ``.envfuse-rts.*`` folders in ``folder`` while it runs, bytes (polled by a
    thread every 0.5 s)."""

    def __init__(self, folder: Path):
        import threading

        self.folder, self.peak, self._done = folder, 0, threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()

    def _poll(self) -> None:
        while not self._done.wait(0.5):
            size = 0
            for d in self.folder.glob(".envfuse-rts.*"):
                for f in d.glob("*"):
                    try:
                        size += f.stat().st_size
                    except OSError:         # removed as we looked
                        pass
            self.peak = max(self.peak, size)

    def stop(self) -> int:
        self._done.set()
        self._thread.join()
        return self.peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2-minute walks, 4 walks")
    ap.add_argument("--breakdown-only", action="store_true",
                    help="3 walks (2 to train, 1 timed): the per-stage breakdown, no evaluate scaling")
    ap.add_argument("--evaluate-only", action="store_true",
                    help="2 training walks of 120 s, then only the evaluate figures (section 3)")
    ap.add_argument("--eval-walk-s", type=float, default=60.0, help="length of each of the 16 evaluated walks (s)")
    ap.add_argument("--simulator-only", action="store_true",
                    help="only the simulator's figures (section 4): a 10-minute walk, per stream, memory")
    ap.add_argument("--memory-only", action="store_true",
                    help="2 training walks of 120 s, then only the peak memory of run on 10-minute and 8-hour walks")
    ap.add_argument("--long-h", type=float, default=8.0, help="length of --memory-only's long walk, hours")
    ap.add_argument("--segment-s", type=float, default=None, help="run's --segment-s in section 5 (default: run's)")
    ap.add_argument("--method", default=None, help="run's --method in section 5 (default: run's)")
    args = ap.parse_args()
    if args.simulator_only:
        with tempfile.TemporaryDirectory() as d:
            simulator_section(Path(d), 120.0 if args.quick else 600.0)
        return
    if args.memory_only:
        with tempfile.TemporaryDirectory() as d:
            walks, model_dir = build(Path(d), 120.0, 2)
            memory_section(Path(d), model_dir, long_h=args.long_h, segment_s=args.segment_s, method=args.method)
        return
    walk_s, n_walks = (120.0, 4) if args.quick else (600.0, 8)
    if args.breakdown_only:
        n_walks = 3
    if args.evaluate_only:
        walk_s, n_walks = 120.0, 2
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        t0 = time.perf_counter()
        walks, model_dir = build(tmp, walk_s, n_walks)
        print(f"built {n_walks} walks of {walk_s:.0f} s and a model in {time.perf_counter() - t0:.0f} s")
        if not args.evaluate_only:
            timing_sections(walks, model_dir, walk_s)
        if args.breakdown_only:
            return
        t0 = time.perf_counter()
        eval_walks = build_eval_walks(tmp, args.eval_walk_s)
        print(f"built 16 walks of {args.eval_walk_s:.0f} s to evaluate in {time.perf_counter() - t0:.0f} s")
        evaluate_section(eval_walks, model_dir, tmp, args.eval_walk_s)
        if not (args.evaluate_only or args.breakdown_only):     # every figure of issue 25 in one run
            simulator_section(tmp, walk_s)
            memory_section(tmp, model_dir, long_h=args.long_h, segment_s=args.segment_s, method=args.method)


def timing_sections(walks, model_dir: Path, walk_s: float) -> None:
    """Sections 1 and 2: raw files to the adaptive track, the per-stage breakdown, fusion alone."""
    rate, n_events, step_rates = pipeline_rate(walks[-1], model_dir)
    yard, yard_warm = oaconvolve_rate(walks[-1] / "audio.wav")
    print(f"raw files -> adaptive track, one core, walk {walks[-1].name} (walk seed {40 + len(walks) - 1}): "
          f"{rate:,.0f}x real time (oaconvolve matched filter in the same run: first run {yard:,.0f}x, ratio "
          f"{rate / yard:.3f}; best of 3 {yard_warm:,.0f}x, ratio {rate / yard_warm:.3f}; target 1,000x and a "
          f"ratio of 0.5 to the best of 3)")
    cli = cli_run_rate(walks[-1], model_dir, walk_s)
    (w_def, c_def), (w_whole, c_whole), (w_imp, c_imp) = cli["default"], cli["whole"], cli["imports"]
    print(f"envfuse run as a user runs it (a new process; default method and segments; best of 3 wall): "
          f"{walk_s / w_def:,.0f}x real time ({w_def:.2f} s wall, CPU {c_def:.2f} s; ratio {walk_s / w_def / yard_warm:.3f}); "
          f"fused whole (--segment-s past the walk) {walk_s / w_whole:,.0f}x ({w_whole:.2f} s, CPU {c_whole:.2f} s); "
          f"of either, the interpreter's start and run's imports {w_imp:.2f} s (CPU {c_imp:.2f} s)")
    stages = stage_breakdown(walks[-1], model_dir)
    total = sum(stages.values())
    print(f"breakdown of one run (CPU s, best of 5; sum {total:.3f} s = {walk_s / total:,.0f}x real time, "
          f"ratio to oaconvolve's best of 3 {walk_s / total / yard_warm:.3f}):")
    for name, sec in stages.items():
        print(f"  {name:36s} {sec:7.3f} s  {100 * sec / total:5.1f} %  ({walk_s / sec:,.0f}x real time)")
    floor = receiver_floor(walks[-1])
    inner = sum(floor["inside"].values())
    others = total - stages["acoustic receiver"]
    top = ", ".join(f"{k} {v:.3f}" for k, v in sorted(floor["inside"].items(), key=lambda kv: -kv[1])[:6])
    print(f"acoustic receiver's floor (best of 5, wall, with timers): {floor['wall_s']:.3f} s, of which "
          f"{inner:.3f} s ({100 * inner / floor['wall_s']:.0f} %) inside compiled kernels, FFTs and numpy sorts "
          f"({top}, ...); were all the Python around them free, raw files -> track would take at least "
          f"{inner + others:.3f} s with the other stages' {others:.3f} s: at most {walk_s / (inner + others):,.0f}x "
          f"real time (target 1,000x)")
    n_events, n_steps = n_events
    print(f"fusion alone on a {walk_s:.0f} s walk, best of 3: filter events (a predict or an update; "
          f"{n_events:,} in all: {n_steps:,} PDR heel strikes cut at the fixes inside them, GNSS and acoustic "
          f"fixes) per second, and PDR heel strikes per second")
    for m, r in step_rates.items():
        if isinstance(r, str):
            print(f"  {m:16s} skipped: {r}")
        else:
            print(f"  {m:16s} {r:12,.0f} events/s {r * n_steps / n_events:12,.0f} heel strikes/s")


# ---------------------------------------------------------------------------------------------------------------
# Section 4: the simulator (issue 25 item 2)
# ---------------------------------------------------------------------------------------------------------------

def _simulator_child(site_dir: str, out_dir: str, duration_s: float, seed: int, breakdown: bool) -> dict:
    """In a fresh (spawned) process: simulate one walk end to end (``simulate_walk``), or stream by stream with
    each stream's simulation and file writing timed apart; returns wall/CPU seconds and the process's peak RSS
    (VmHWM) beside its resident set after the imports."""
    from dataclasses import replace as dc_replace
    from features.fileio import atomic_write_text
    from features.site import load_site
    from simulation.gnss import fix as gnss_fix
    from simulation.gnss.nmea_writer import format_nmea
    from simulation.gnss.stream import simulate_gnss, to_nmea_epochs
    from simulation.imu.stream import imu_csv_text, simulate_imu, truth_steps_csv_text
    from simulation.acoustic.stream import write_audio
    from features.uwb.reader import write_uwb
    from simulation.imu.foot import IMU_FOOT_FILE, foot_csv_text, simulate_foot_imu
    from simulation.uwb.stream import UWB_FILE, simulate_uwb
    from simulation.rng import stream_rng
    from simulation.site.route import RouteConfig, plan_route, route_trajectory
    from simulation.streams import StreamContext
    from simulation.walk import default_start_utc, device_height_m, simulate_walk, write_truth_csv

    rss0_mib = int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    out = Path(out_dir)
    times: dict[str, float] = {}
    c0, t0 = time.process_time(), time.perf_counter()
    if not breakdown:
        simulate_walk(site_dir, out, seed=seed, duration_s=duration_s, progress=False, overwrite=True)
    else:
        out.mkdir(parents=True, exist_ok=True)
        site = load_site(Path(site_dir) / "site.toml")
        route = RouteConfig()
        poly, stops, speed = plan_route(site, stream_rng(seed, "route"), duration_s, route)
        traj = route_trajectory(poly, stops, speed, duration_s, default_start_utc(seed), device_height_m(site, seed),
                                route)
        ctx = StreamContext(site=site, trajectory=traj, out_dir=out, seed=seed, kind="walk", person_seed=seed,
                            options={"progress": False})
        mark = time.process_time()

        def lap(name: str) -> None:
            nonlocal mark
            now = time.process_time()
            times[name] = now - mark
            mark = now

        sim = simulate_gnss(site, traj, seed, fix_cfg=dc_replace(gnss_fix.FixConfig(), rtk_cold_start=True),
                            receiver_seed=seed, body=True)
        lap("GNSS: simulate_gnss")
        atomic_write_text(out / "gnss.nmea", format_nmea(to_nmea_epochs(sim, site, seed, traj, gst=True)))
        lap("GNSS: NMEA text and file")
        imu, steps = simulate_imu(ctx)
        lap("IMU: simulate_imu")
        atomic_write_text(out / "imu.csv", imu_csv_text(imu))
        atomic_write_text(out / "truth_steps.csv", truth_steps_csv_text(steps))
        lap("IMU: CSV text and files")
        write_audio(ctx)
        lap("audio: render_audio (WAV, CSV within)")
        if site.uwb_anchors:
            uwb_log, _ = simulate_uwb(ctx)
            lap("UWB: simulate_uwb")
            write_uwb(out / UWB_FILE, uwb_log)
            lap("UWB: CSV text and file")
        foot, _ = simulate_foot_imu(ctx)
        lap("foot IMU: simulate_foot_imu")
        atomic_write_text(out / IMU_FOOT_FILE, foot_csv_text(foot))
        lap("foot IMU: CSV text and file")
        write_truth_csv(out / "truth.csv", site, traj)
        lap("truth.csv")
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if breakdown:           # the WAV's writing alone: the same int16 samples written again block by block
        import soundfile
        x, fs = soundfile.read(str(out / "audio.wav"), dtype="int16")
        t1 = time.process_time()
        with soundfile.SoundFile(str(out / "rewrite.wav"), "w", samplerate=fs, channels=1, subtype="PCM_16") as f:
            for i in range(0, len(x), 1 << 16):
                f.write(x[i:i + (1 << 16)])
        times["audio: of which WAV writing (re-timed)"] = time.process_time() - t1
        (out / "rewrite.wav").unlink()
    return {"wall_s": wall, "cpu_s": cpu, "times": times, "rss0_mib": rss0_mib,
            "peak_rss_mib": _vm_hwm_mib()}


def _vm_hwm_mib() -> float:
    """This process's peak resident memory since its exec (VmHWM, MiB; see :func:`_peak_rss_task`)."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmHWM:"))


def _in_child(*args) -> dict:
    """Run :func:`_simulator_child` in a spawned interpreter (nothing inherited: its RSS is the simulator's)."""
    import multiprocessing
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(_simulator_child, args)


def simulator_section(tmp: Path, duration_s: float = 600.0, site_seed: int = 5, seed: int = 40,
                      repeat: int = 2) -> dict:
    """Section 4: the simulator's × real time on a ``duration_s`` walk (best of ``repeat`` end-to-end runs, each
    in a fresh process), the breakdown per stream, peak memory, and oaconvolve over the walk's audio."""
    from features.site import save_site
    from simulation.site.layout import generate_site

    site = tmp / "sim_site"
    site.mkdir(exist_ok=True)
    save_site(generate_site(site_seed), site / "site.toml")
    warm = _in_child(str(site), str(tmp / "sim_warm"), 20.0, seed, False)      # numba's on-disk cache filled
    runs = [_in_child(str(site), str(tmp / "sim_walk"), duration_s, seed, False) for _ in range(repeat)]
    parts = _in_child(str(site), str(tmp / "sim_parts"), duration_s, seed, True)
    yard, yard_best = oaconvolve_rate(tmp / "sim_walk" / "audio.wav")
    best = min(runs, key=lambda r: r["wall_s"])
    rate = duration_s / best["wall_s"]
    walls = ", ".join(f"{r['wall_s']:.2f}" for r in runs)
    print(f"simulator, a {duration_s:.0f} s walk end to end (simulate_walk, every file written; best of {repeat} "
          f"fresh processes, {walls} s wall): {rate:,.1f}x real time "
          f"(CPU {best['cpu_s']:.2f} s: {duration_s / best['cpu_s']:,.1f}x; target 100x); oaconvolve over its audio "
          f"in the same run: first run {yard:,.0f}x, best of 3 {yard_best:,.0f}x, ratio {rate / yard_best:.4f}; "
          f"a 20 s walk in a new process first: {warm['wall_s']:.2f} s")
    print(f"  peak RSS of the simulating process {best['peak_rss_mib']:.0f} MiB ({best['rss0_mib']:.0f} MiB after "
          f"its imports); the stream-by-stream run's {parts['peak_rss_mib']:.0f} MiB")
    total = sum(v for k, v in parts["times"].items() if "re-timed" not in k)
    print(f"  per stream (one run, CPU s of the process, a fairer clock than wall time on a shared machine; sum "
          f"{total:.2f} s = {duration_s / total:,.1f}x real time):")
    for name, sec in parts["times"].items():
        print(f"    {name:40s} {sec:7.2f} s  {100 * sec / total:5.1f} %  ({duration_s / sec:,.0f}x real time)")
    return {"rate": rate, "yard_best": yard_best, "best": best, "parts": parts}


if __name__ == "__main__":
    main()
