"""Band-pass + matched filter for beacon chirps, streamed in blocks with flat memory.

The receiver correlates the recording with the known transmitted chirp
(pulse compression; Turin 1960, "An introduction to matched filters", IRE
Trans. IT-6(3)): for a linear FM chirp of bandwidth B the output main lobe is
about 1/B wide, so a 6 kHz chirp resolves paths about 170 µs (8 samples at
48 kHz) apart.

Three linear operations are folded into one FIR kernel per template, because
convolution is associative:

* the 16.5–23.5 kHz band-pass of docs/design.md §5 (a linear-phase windowed-sinc
  FIR from :func:`scipy.signal.firwin`),
* the matched filter: the time-reversed chirp, weighted on receive by a
  Kaiser window (β = 6). Unweighted, a linear-FM chirp's compressed pulse has
  range sidelobes at −13.5 dB (here, with the Tukey 0.2 taper), above the
  −20 dB tap threshold of docs/design.md §5, so every path would bring false taps
  and a false "first arrival" ahead of it. Amplitude weighting of the
  reference (Richards, "Fundamentals of Radar Signal Processing", 2nd ed.,
  §4.7.3) lowers them to −34.6 dB for 1.2 dB of SNR and a 1.7× wider main
  lobe (measured in ``tests/test_matched_filter.py``).

The envelope is the magnitude of the analytic output (positive frequencies
doubled, :func:`analytic_convolve`).

The kernels run as a *batched overlap-save* convolution (Oppenheim & Schafer,
"Discrete-Time Signal Processing", 3rd ed., §8.7.3): each incoming block is cut
into overlapping segments of ``nfft`` samples, all segments are transformed in
one ``scipy.fft.rfft`` call, multiplied by every kernel spectrum and inverse
transformed in one call. Hand-written (instead of :func:`scipy.signal.oaconvolve`)
because it streams: the last ``kernel_len − 1`` input samples are carried over
to the next block, so the output of a file processed in blocks equals the output
of the whole file, and memory is bounded by the block size. It is also about
2.5× faster than ``oaconvolve`` here (see ``bench/bench_audio.py``; its own
costs against the two FFT calls it cannot avoid: ``bench/bench_frontend.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from features.errors import ConfigError

__all__ = [
    "ChirpSpec", "chirp_template", "bandpass_fir", "MatchedFilterBank", "StreamingMatchedFilter", "analytic_convolve",
    "default_nfft",
    "BANDPASS_LOW_HZ", "BANDPASS_HIGH_HZ",
]

BANDPASS_LOW_HZ = 16_500.0
"""Lower edge of the receiver band-pass, Hz (docs/design.md §5)."""

BANDPASS_HIGH_HZ = 23_500.0
"""Upper edge of the receiver band-pass, Hz (docs/design.md §5)."""

RECEIVE_WINDOW = ("kaiser", 6.0)
"""Receive-side amplitude weighting of the reference chirp (:func:`scipy.signal.get_window` spec)."""

_BANDPASS_TAPS = 127
"""Band-pass FIR length (odd, so the group delay is a whole number of samples: 63)."""


@dataclass(frozen=True)
class ChirpSpec:
    """A linear up-chirp as a beacon transmits it.

    ``taper_fraction`` is the Tukey window's ``alpha`` (fraction of the chirp
    inside the cosine tapers; 0 = rectangular, 1 = Hann).
    """

    f0_hz: float
    f1_hz: float
    duration_s: float
    taper_fraction: float

    def __post_init__(self):
        for name in ("f0_hz", "f1_hz", "duration_s", "taper_fraction"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise ConfigError(f"chirp {name} must be finite, got {value!r}")
        if not 0 < self.f0_hz < self.f1_hz:
            raise ConfigError(f"chirp band must satisfy 0 < f0_hz < f1_hz, got {self.f0_hz}..{self.f1_hz}")
        if self.duration_s <= 0:
            raise ConfigError(f"chirp duration_s must be positive, got {self.duration_s}")
        if not 0.0 <= self.taper_fraction <= 1.0:
            raise ConfigError(f"chirp taper_fraction must lie in [0, 1], got {self.taper_fraction}")

    @property
    def bandwidth_hz(self) -> float:
        return self.f1_hz - self.f0_hz

    @property
    def range_doppler_lag_s(self) -> float:
        """Range–Doppler coupling of the linear chirp: the matched-filter peak moves by −(η − 1)·this, s.

        A receiver closing on the beacon at v_r hears s(η·(t − t_a)), η = 1 + v_r/c
        (moving observer): every frequency scaled by η and the sweep rate k by η².
        Aligning the heard instantaneous frequency η·f0 + η²·k·u with the template's
        f0 + k·(u − L) at the chirp's centre (u = T/2), to first order in η − 1,

            L = −(η − 1)·(f0/k + T) = −(η − 1)·T·f1/B,

        the LFM's range–Doppler coupling (Levanon & Mozeson, "Radar Signals", 2004,
        §4.2, where a frequency offset Δf moves the peak by −Δf·T/B; the time
        compression adds the f0 → f1 of the centre). The range read is therefore
        c·L = −v_r·T·f1/B too short when closing: ρ = r(t_a) + ṙ·T·f1/B ≈ r(t_a + T·f1/B),
        the range T·f1/B later (38.3 ms for 17→23 kHz in 10 ms). On a Doppler-scaled
        simulated chirp the peak moves by −38.2 ms per unit η − 1 (a test checks).

        >>> round(ChirpSpec(17000.0, 23000.0, 0.010, 0.2).range_doppler_lag_s * 1e3, 2)
        38.33
        """
        return self.duration_s * self.f1_hz / (self.f1_hz - self.f0_hz)


def chirp_template(spec: ChirpSpec, fs_hz: float) -> np.ndarray:
    """The transmitted chirp sampled at ``fs_hz``: shape ``(round(duration·fs),)``, peak 1.

    s(t) = w(t)·sin(2π(f0·t + (f1 − f0)·t²/(2T))), 0 ≤ t < T, with w a Tukey
    window (:func:`scipy.signal.chirp`, method ``linear``, ``phi=-90``), as
    docs/beacon_protocol.md defines it. (The envelope detector does not depend
    on the carrier phase.)

    >>> s = chirp_template(ChirpSpec(17000.0, 23000.0, 0.010, 0.2), 48000)
    >>> s.shape, round(float(abs(s).max()), 3)
    ((480,), 1.0)
    """
    if spec.f1_hz >= fs_hz / 2:
        raise ConfigError(f"chirp upper frequency {spec.f1_hz} Hz is not below Nyquist ({fs_hz / 2} Hz)")
    n = int(round(spec.duration_s * fs_hz))
    if n < 8:
        raise ConfigError(f"chirp of {spec.duration_s} s has fewer than 8 samples at {fs_hz} Hz")
    t = np.arange(n) / fs_hz
    k = (spec.f1_hz - spec.f0_hz) / spec.duration_s
    # scipy.signal.chirp(method="linear", phi=-90): cos(2π(f0·t + k·t²/2) − π/2) = sin(...).
    s = np.cos(2.0 * np.pi * (spec.f0_hz * t + 0.5 * k * t * t) - 0.5 * np.pi)
    return s * _tukey(n, spec.taper_fraction)


# Written out (as scipy.signal.windows.tukey and scipy.signal.firwin define them, checked
# against them in tests/test_matched_filter.py) because importing scipy.signal, which pulls
# in scipy.stats, costs about 1.4 s of start-up: more than the receiver spends on a
# two-minute recording.


def _tukey(n: int, alpha: float) -> np.ndarray:
    """Symmetric Tukey window of ``n`` points, taper fraction ``alpha`` (Harris 1978, Proc. IEEE 66(1)).

    >>> _tukey(5, 0.5).round(3).tolist()
    [0.0, 1.0, 1.0, 1.0, 0.0]
    """
    if alpha <= 0:
        return np.ones(n)
    if alpha >= 1:
        return np.hanning(n)
    x = np.arange(n) / (n - 1)
    w = np.ones(n)
    lo, hi = x < alpha / 2, x > 1 - alpha / 2
    w[lo] = 0.5 * (1 + np.cos(np.pi * (2 * x[lo] / alpha - 1)))
    w[hi] = 0.5 * (1 + np.cos(np.pi * (2 * x[hi] / alpha - 2 / alpha + 1)))
    return w


def _firwin_bandpass(n_taps: int, low_hz: float, high_hz: float, fs_hz: float) -> np.ndarray:
    """Windowed-sinc band-pass FIR (Hamming), unit gain at the band centre: scipy.signal.firwin's
    ``firwin(n_taps, [low, high], pass_zero=False, fs=fs)`` (Oppenheim & Schafer, §7.5)."""
    nyq = fs_hz / 2
    lo, hi = low_hz / nyq, high_hz / nyq
    m = np.arange(n_taps) - (n_taps - 1) / 2
    h = hi * np.sinc(hi * m) - lo * np.sinc(lo * m)
    h *= np.hamming(n_taps)
    return h / np.sum(h * np.cos(np.pi * m * 0.5 * (lo + hi)))


def bandpass_fir(fs_hz: float, low_hz: float = BANDPASS_LOW_HZ, high_hz: float = BANDPASS_HIGH_HZ,
                 n_taps: int = _BANDPASS_TAPS) -> np.ndarray:
    """Linear-phase band-pass FIR, shape ``(n_taps,)`` (window method, Hamming; :func:`scipy.signal.firwin`).

    The upper edge is clipped below Nyquist when ``fs_hz`` cannot carry it.

    >>> h = bandpass_fir(48000)
    >>> h.shape, bool(np.allclose(h, h[::-1]))
    ((127,), True)
    """
    high = min(high_hz, 0.49 * fs_hz)
    if not 0 < low_hz < high:
        raise ConfigError(f"band-pass {low_hz}..{high_hz} Hz does not fit below Nyquist at fs={fs_hz} Hz")
    return _firwin_bandpass(n_taps, low_hz, high, fs_hz)


class MatchedFilterBank:
    """Matched-filter kernels (band-pass folded in) for one or more chirp templates.

    Parameters
    ----------
    specs : sequence of ChirpSpec
        One entry per distinct chirp (beacons sharing a chirp share a template).
    fs_hz : float
        Sample rate of the audio.

    Attributes
    ----------
    kernels : ndarray of shape (n_templates, kernel_len)
        Band-pass ∗ time-reversed chirp, scaled so that the envelope of the
        noise-free template equals 1 at its peak.
    delay_samples : int
        A chirp starting at input sample ``s`` peaks at convolution output ``s + delay_samples``.
    noise_gain : ndarray of shape (n_templates,)
        ``sqrt(sum(kernel²))``: white noise of standard deviation σ gives an
        analytic output whose real and imaginary parts have standard deviation
        about ``σ·noise_gain``, i.e. a Rayleigh envelope with that scale.
    mainlobe_s : ndarray of shape (n_templates,)
        Full width of the compressed pulse's main lobe above −20 dB, s: the
        extent of one path in the CIR.
    """

    def __init__(self, specs, fs_hz: float):
        self.specs = tuple(specs)
        if not self.specs:
            raise ConfigError("matched filter needs at least one chirp template")
        self.fs_hz = float(fs_hz)
        bp = bandpass_fir(self.fs_hz)
        templates = [chirp_template(s, self.fs_hz) for s in self.specs]
        self.template_len = max(len(t) for t in templates)
        rows = []
        widths = []
        for s in templates:
            padded = np.zeros(self.template_len)
            padded[: len(s)] = s
            reference = s * np.kaiser(len(s), RECEIVE_WINDOW[1])      # symmetric Kaiser, β = 6
            ref_padded = np.zeros(self.template_len)
            ref_padded[: len(s)] = reference
            kernel = np.convolve(bp, ref_padded[::-1])
            env = analytic_convolve(padded, kernel, np.abs)
            rows.append(kernel / env.max())
            widths.append(np.count_nonzero(env >= 0.1 * env.max()) / self.fs_hz)
        self.mainlobe_s = np.asarray(widths)
        self.kernels = np.asarray(rows)
        self.kernel_len = self.kernels.shape[1]
        self.delay_samples = (self.template_len - 1) + (len(bp) - 1) // 2
        self.noise_gain = np.sqrt(np.sum(self.kernels ** 2, axis=1))
        self._spectra: dict = {}

    @property
    def n_templates(self) -> int:
        return len(self.specs)

    def envelope(self, x: np.ndarray, template: int, n_out: int | None = None) -> np.ndarray:
        """Full-rate matched-filter envelope of short signals for one template.

        ``x`` of shape (m,) or (n, m) gives the same shape: element ``s`` is the
        envelope for a chirp starting at ``x[..., s]``; the last ``kernel_len``
        elements see zeros beyond ``x``. ``n_out`` keeps only the first ``n_out``
        elements (shape (..., n_out)), which allows a shorter FFT: the circular
        convolution of size N equals the linear one at outputs ``delay_samples + s``
        for ``s < n_out`` when N ≥ delay + n_out and N ≥ m + kernel_len − 1 − delay
        (no wrapped-round output lands there). The kernel spectrum is cached per FFT
        size, so a batch of snippets costs one real and one complex FFT call.
        """
        x = np.asarray(x, dtype=np.float32)
        m = x.shape[-1]
        if n_out is None:
            n_out = m
        n_out = min(int(n_out), m)
        n = max(self.delay_samples + n_out, m + self.kernel_len - 1 - self.delay_samples, m)
        nfft = scipy.fft.next_fast_len(n)
        key = (nfft, template)
        spectrum = self._spectra.get(key)
        if spectrum is None:
            h = scipy.fft.rfft(self.kernels[template], nfft)
            # Analytic signal: positive frequencies doubled, negative ones zero (DC and Nyquist once).
            spectrum = np.zeros(nfft, dtype=np.complex64)
            half = nfft // 2
            spectrum[0] = h[0]
            spectrum[1: half + (nfft % 2)] = 2.0 * h[1: half + (nfft % 2)]
            if nfft % 2 == 0:
                spectrum[half] = h[half]
            self._spectra[key] = spectrum
        xf = scipy.fft.rfft(x, nfft, axis=-1)
        full = np.zeros(x.shape[:-1] + (nfft,), dtype=np.complex64)
        full[..., : xf.shape[-1]] = xf
        z = scipy.fft.ifft(full * spectrum, axis=-1)
        return np.abs(z[..., self.delay_samples: self.delay_samples + n_out])


def analytic_convolve(x: np.ndarray, h: np.ndarray, post=None) -> np.ndarray:
    """Analytic signal of the full linear convolution ``x ∗ h`` (length len(x) + len(h) − 1).

    The analytic signal keeps the positive-frequency half of the spectrum,
    doubled (Gabor 1946); its magnitude is the envelope. ``post`` (e.g.
    ``np.abs``) is applied before returning.

    >>> z = analytic_convolve(np.cos(2 * np.pi * 0.1 * np.arange(200)), np.array([1.0]))
    >>> round(float(np.abs(z[50:150]).mean()), 2)
    1.0
    """
    n = len(x) + len(h) - 1
    nfft = scipy.fft.next_fast_len(n)
    spec = scipy.fft.rfft(x, nfft) * scipy.fft.rfft(h, nfft)
    full = np.zeros(nfft, dtype=complex)
    half = nfft // 2
    full[0] = spec[0]
    full[1: half + (nfft % 2)] = 2.0 * spec[1: half + (nfft % 2)]
    if nfft % 2 == 0:
        full[half] = spec[half]
    z = scipy.fft.ifft(full)[:n]
    return post(z) if post is not None else z


def default_nfft(kernel_len: int, decimation: int = 4) -> int:
    """Overlap-save segment length for a kernel of ``kernel_len`` taps: the smallest power of two
    (at least 4096, made a multiple of ``decimation``) that is at least 6 · kernel_len.

    Each segment of N samples yields N − kernel_len + 1 outputs, so short segments waste
    more on the overlap; long ones cost more per sample (scipy's pocketfft, float32, batched,
    on the development machine: 3.5 ns per sample at N = 4096, 4.1 at 8192, 4.3 at 16384).
    Over the whole filter, for the 10 ms chirp (609 taps, 15 % overlap) 4096 was 7–22 % faster
    than 8192 in repeated runs (``bench/bench_frontend.py``); for a 20 ms chirp (1089 taps) 8192
    was 6–8 % faster than 4096.

    >>> default_nfft(609), default_nfft(1089), default_nfft(3000)
    (4096, 8192, 32768)
    """
    n = 1 << max(12, int(math.ceil(math.log2(6 * kernel_len))))
    return int(math.ceil(n / decimation)) * decimation


class StreamingMatchedFilter:
    """Decimated matched-filter envelopes of a block stream, by batched overlap-save.

    Detection does not need every sample of the envelope: the analytic output
    of a 16.5–23.5 kHz filter occupies a 7 kHz band, so it is computed at
    ``fs / decimation`` by keeping only the ``nfft / decimation`` spectrum bins
    around the band and inverse-transforming those (frequency-domain
    decimation: sampling the N-point IDFT at every D-th point equals a
    (N/D)-point IDFT of the shifted band when no other bin is occupied;
    Crochiere & Rabiner 1983 §7). With D = 4 (12 kHz complex rate, 4 samples
    per output) the envelope of a 6 kHz chirp is at most 0.9 dB below its peak
    between outputs. Arrival times come from these outputs themselves (a
    log-parabola through the first path's lobe, :mod:`features.acoustic.cir`), which on
    simulated walks agree with the full-rate envelope of
    :meth:`MatchedFilterBank.envelope` to a median 0.03 samples.

    ``process(block)`` returns ``(j0, env)``: ``env`` of shape
    ``(n_templates, m)``, column ``c`` being the envelope of a chirp that starts
    at input sample ``decimation·(j0 + c) − delay_samples``. Output of a stream
    cut into any blocks equals the output of one block.

    ``first_index``: the stream index of the first sample fed (a cut of a longer recording: its index in
    the whole); ``j0`` and the decimation grid are then the whole stream's (column ``c`` of the first call is
    for a chirp starting at ``decimation·(j0 + c) − delay_samples`` in the whole's samples), and a cut fed
    the same blocks as the whole from some sample on gives the whole's outputs from there on (the segments of
    each block start where the whole's do).

    ``nfft`` (segment length) defaults to :func:`default_nfft`. The input
    buffer (carried-over tail, block, zero padding) and the band products are
    allocated once and reused, so a block costs one real FFT call, one
    multiply, one inverse FFT call and one magnitude, with no concatenation.
    """

    def __init__(self, bank: MatchedFilterBank, nfft: int | None = None, decimation: int = 4, first_index: int = 0):
        d = int(decimation)
        if d < 1:
            raise ConfigError(f"decimation {decimation} must be a positive integer")
        # Pad the kernel with zeros so that kernel_len − 1 is a multiple of D.
        self.kernel_len = int(math.ceil((bank.kernel_len - 1) / d)) * d + 1
        if nfft is None:
            nfft = default_nfft(self.kernel_len, d)
        if nfft % d:
            raise ConfigError(f"decimation {decimation} must be a positive divisor of nfft {nfft}")
        if nfft < 2 * self.kernel_len:
            raise ConfigError(f"nfft {nfft} must be at least twice the kernel length {self.kernel_len}")
        self.bank = bank
        self.nfft = int(nfft)
        self.decimation = d
        self.hop = ((self.nfft - self.kernel_len + 1) // d) * d
        df_hz = bank.fs_hz / self.nfft
        n_keep = self.nfft // d
        width_hz = n_keep * df_hz
        centre_hz = 0.5 * (BANDPASS_LOW_HZ + min(BANDPASS_HIGH_HZ, bank.fs_hz / 2))
        self._k0 = max(0, int(round((centre_hz - width_hz / 2) / df_hz)))
        spectra = scipy.fft.rfft(bank.kernels, n=self.nfft, axis=1)
        # Bins of the kept band below Nyquist; those above it (if any) are zero in every product.
        self._n_band = min(n_keep, spectra.shape[1] - self._k0)
        # Every D-th output of the N-point IDFT, z[D·m] = (1/N) Σ_band Y[k] e^{2πi·k·m/(N/D)}, is the
        # unscaled (N/D)-point IDFT of the band (times a unit phase) over N; the analytic signal
        # doubles positive frequencies. Hence 2/N here and an unscaled inverse (norm="forward").
        self._spectra = (2.0 / self.nfft * spectra[:, self._k0: self._k0 + self._n_band]).astype(np.complex64)
        self._n_keep = n_keep
        # A cut of a longer recording (``first_index``: its first sample's index in the whole) is preceded by
        # zeros back to a whole multiple of D: its outputs fall on the whole's decimation grid and index.
        phase = int(first_index) % d
        self._pending = np.zeros(phase, dtype=np.float32)
        self._next_j = (int(first_index) - phase) // d
        self._received = 0
        self._first_valid = (self.kernel_len - 1) // d
        # Work buffers, grown to the largest block seen (memory is bounded by the block size):
        # input = the last kernel_len − 1 samples carried over, then the block, then zeros;
        # band products, whose bins above Nyquist stay zero.
        self._set_input(np.zeros(self.nfft, dtype=np.float32))
        self._products = np.zeros((bank.n_templates, 0, n_keep), dtype=np.complex64)

    def _set_input(self, data: np.ndarray) -> None:
        """Use ``data`` as the input buffer, with its overlapping segments as a read-only view
        made once (``as_strided`` costs about as much per call as a small FFT)."""
        self._input = data
        n_seg = (len(data) - self.nfft) // self.hop + 1
        self._segments = np.lib.stride_tricks.as_strided(
            data, shape=(n_seg, self.nfft), strides=(self.hop * data.strides[0], data.strides[0]), writeable=False)

    def chirp_start(self, j):
        """Input sample index at which a chirp starts for decimated output index ``j``."""
        return self.decimation * np.asarray(j) - self.bank.delay_samples

    def _envelope(self, x: np.ndarray) -> np.ndarray:
        """Decimated envelopes for ``x`` (len multiple of D), float32 of shape (n_templates, len(x) / D)."""
        n = len(x)
        n_out = n // self.decimation
        if n == 0:
            return np.zeros((self.bank.n_templates, 0), dtype=np.float32)
        carry = self.kernel_len - 1
        n_seg = -(-n // self.hop)
        need = (n_seg - 1) * self.hop + self.nfft
        data = self._input
        if len(data) < need:
            data = np.zeros(need, dtype=np.float32)
            data[:carry] = self._input[:carry]
            self._set_input(data)
        data[carry: carry + n] = x
        data[carry + n: need] = 0.0
        spec = scipy.fft.rfft(self._segments[:n_seg], axis=1, workers=1)
        data[:carry] = data[n: n + carry]          # carried over to the next block
        if self._products.shape[1] < n_seg:
            self._products = np.zeros((self.bank.n_templates, n_seg, self._n_keep), dtype=np.complex64)
        products = self._products[:, :n_seg]
        # Y_k = X · H_k for every template k and segment, then one batched inverse FFT, in place.
        np.multiply(spec[None, :, self._k0: self._k0 + self._n_band], self._spectra[:, None, :],
                    out=products[:, :, : self._n_band])
        products[:, :, self._n_band:] = 0.0
        z = scipy.fft.ifft(products, axis=2, workers=1, norm="forward", overwrite_x=True)
        # Overlap-save: outputs before kernel_len − 1 wrap around; keep hop / D after them.
        env = np.abs(z[:, :, self._first_valid: self._first_valid + self.hop // self.decimation])
        return env.reshape(env.shape[0], -1)[:, :n_out]

    def process(self, block: np.ndarray) -> tuple[int, np.ndarray]:
        """Feed one block (1-D float); return ``(j0, envelopes)`` as described in the class docstring."""
        x = np.asarray(block, dtype=np.float32).ravel()
        self._received += len(x)
        if len(self._pending):
            x = np.concatenate([self._pending, x])
        usable = (len(x) // self.decimation) * self.decimation
        self._pending = x[usable:].copy()
        env = self._envelope(x[:usable])
        j0 = self._next_j
        self._next_j += env.shape[1]
        return j0, env

    def flush(self) -> tuple[int, np.ndarray]:
        """Feed trailing zeros so every chirp start up to the last input sample has an output."""
        pad = self.bank.delay_samples + self.decimation
        j0, env = self.process(np.zeros(pad, dtype=np.float32))
        self._received -= pad
        return j0, env
