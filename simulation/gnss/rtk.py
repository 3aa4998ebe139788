"""The simulated receiver's RTK engine: float ambiguities, integer resolution, fix-and-hold and its validation.

Everything the engine decides is decided from what a receiver has — its
carriers, its code-minus-carrier ambiguity estimates, its own (white-noise)
error model — never from the simulator's truth. The truth enters only as
physics: the actual errors of the carriers (an NLOS carrier measures the
reflected path) and of the codes (multipath and NLOS biases held while the
carrier stays locked), which make the float ambiguities biased in ways the
receiver's model does not know (Teunissen 2001, "Integer estimation in the
presence of biases", J. Geodesy 75).

Per epoch (arrays (n, k) unless noted; ranges in metres):

1. **Float solution.** Each locked satellite's ambiguity is known from the
   code-minus-carrier since its lock began, λÑ = mean(Φ − P), with the
   receiver's variance s² = σ²_code/N_eff (the filter takes code errors as
   white; N_eff counts ``float_indep_rate_hz`` independent samples a second,
   capped at ``float_weight_window_s`` — its ambiguity process noise forgets
   older data); its error is a = mean(e_Φ − e_P) over the same window
   (:func:`simulation.gnss.fix.float_ambiguity_bias`). The default 0.2 Hz — one
   independent code sample per 5 s, the time a walker takes to cross the
   ≈ 5 m over which code multipath decorrelates — was chosen on tuning sites
   1–4 (1 Hz made 7 % of the open-sky fixed epochs more than 0.2 m wrong,
   0.2 Hz 1 %): a filter that counts every 5 Hz epoch as independent would be
   overconfident by far more than real engines are.
   With the carriers (σ²_φ = a_φ² + (b_φ/sin el)², RTKLIB's default carrier
   model, a = b = 3 mm) the least-squares estimate of position and
   ambiguities gives θ_f from y = Φ − λÑ with weights 1/(s² + σ²_φ), and the
   ambiguity errors e_N = a + A·(e_y − G·θ_f), A = s²/(s² + σ²_φ); their
   covariance by the Woodbury identity Q_N = diag(1/(1/σ²_φ + 1/s²)) +
   U·(GᵀW_fG)⁻¹·Uᵀ, U = diag(A)·G.
2. **Ambiguity resolution** on the AR set — locked satellites above
   ``ar_mask_deg`` whose C/N0 clears an elevation-dependent SNR mask (nominal
   open sky less ``rtk_snr_margin_db``; partial ambiguity resolution as
   RTKLIB's ``pos1-snrmask``) — as double differences against the highest
   satellite of each system: LAMBDA's best and second-best integer vectors
   (:func:`simulation.gnss.ambiguity.lambda_search`), accepted when the ratio
   test passes (≥ ``ratio_threshold``, RTKLIB's 3.0) and the bootstrapping
   success rate of the receiver's own Q reaches ``min_success_rate``
   (Teunissen 1998). If it fails, the satellite with the largest normalised
   float residual is left out and the search redone, up to ``ar_max_drops``
   times. The integers found are the integer *errors* (the search runs on
   the error vector: ILS is translation-invariant by integers): a fix is
   wrong when any is non-zero.
3. **Fix-and-hold.** A fix holds its integers; a satellite that slips or
   leaves drops out; a newly locked one joins with the integer the fixed
   position gives it, so a wrong fix stays wrong as satellites come and go.
   **Validation** each epoch: the carrier residuals of the fixed solution pass
   a χ² test (``validation_pfa``; the worst satellite is dropped while it
   fails, as RTKLIB rejects phase outliers) and the fixed position stays
   within the code (DGNSS) solution's own confidence (χ²₃,
   ``float_check_pfa``; the float solution is no referee, it shares the
   biases that made the fix), a position-jump check; and every
   ``revalidate_s`` the engine searches the current float ambiguities afresh
   (RTKLIB's "continuous" mode does so at every epoch): a confident new
   solution (ratio and success rate pass) more than ``revalidate_shift_m``
   from the held one replaces it. A
   wrong fix therefore persists until lock is lost (fewer than
   ``hold_min_sats`` held) or the geometry has moved enough for validation to
   catch it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from simulation.gnss.ambiguity import bootstrap_success_rate, lambda_search
from simulation.gnss.gst import gst_fields

__all__ = ["RtkConfig", "RtkResult", "carrier_model_var_m2", "float_solution", "rtk_engine"]


@dataclass(frozen=True)
class RtkConfig:
    """Parameters of the RTK engine (module docstring; metres, seconds, degrees, dB as named)."""

    carrier_a_m: float = 0.003
    carrier_b_m: float = 0.003
    float_indep_rate_hz: float = 0.2
    float_weight_window_s: float = 30.0
    ar_mask_deg: float = 15.0
    snr_margin_db: float = 10.0
    min_sats: int = 6
    ratio_threshold: float = 3.0
    min_success_rate: float = 0.99
    ar_max_drops: int = 2
    hold_min_sats: int = 5
    validation_pfa: float = 1e-3
    float_check_pfa: float = 1e-4
    join_max_frac_cycles: float = 0.2
    phase_lock_s: float = 3.0
    revalidate_s: float = 1.0
    revalidate_shift_m: float = 0.05

    def __post_init__(self):
        for name, value in vars(self).items():
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"RtkConfig.{name} must be finite and non-negative, got {value!r}")
        if self.min_sats < 4 or self.hold_min_sats < 4:
            raise ValueError("RtkConfig.min_sats and hold_min_sats must be >= 4")
        if self.ratio_threshold < 1.0 or not 0.0 <= self.min_success_rate <= 1.0:
            raise ValueError("RtkConfig needs ratio_threshold >= 1 and min_success_rate in [0, 1]")
        for name in ("validation_pfa", "float_check_pfa"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(f"RtkConfig.{name} must lie in (0, 1), got {getattr(self, name)}")
        if self.float_indep_rate_hz <= 0 or self.float_weight_window_s <= 0:
            raise ValueError("RtkConfig.float_indep_rate_hz and float_weight_window_s must be positive")


@dataclass(frozen=True, eq=False)
class RtkResult:
    """Engine output per epoch (n,) or (n, 3).

    fixed : bool; fixed_error_enu_m : the fixed solution's error (NaN where not fixed)
    gst : (n, 7) its GST fields (:func:`simulation.gnss.fix.gst_fields` layout: carrier covariance × a-posteriori
    variance factor, RMS of the carrier residuals), NaN where not fixed
    wrong : a fix with integers off by more than one common integer per system (truth, for reports)
    ratio, success_rate : of the last search of the epoch (NaN where none ran)
    """

    fixed: np.ndarray
    fixed_error_enu_m: np.ndarray
    gst: np.ndarray
    wrong: np.ndarray
    ratio: np.ndarray
    success_rate: np.ndarray


def carrier_model_var_m2(el_rad: np.ndarray, cfg: RtkConfig = RtkConfig()) -> np.ndarray:
    """The receiver's carrier-phase variance model, σ²_φ = a² + (b/sin el)², m² (RTKLIB's options ``stats-errphase``
    and ``stats-errphaseel``, 3 mm each by default; Takasu, RTKLIB 2.4.2 manual, App. E.6, measurement error
    model).

    >>> round(float(carrier_model_var_m2(np.radians(30.0))) * 1e6, 1)
    45.0
    """
    s = np.maximum(np.sin(np.asarray(el_rad, float)), 0.05)
    return cfg.carrier_a_m ** 2 + (cfg.carrier_b_m / s) ** 2


def _solve(g: np.ndarray, w: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched WLS θ = (GᵀWG)⁻¹GᵀWy (n, p) and (GᵀWG)⁻¹ (n, p, p); empty clock columns pinned."""
    gw = g * w[..., None]
    nmat = np.matmul(gw.transpose(0, 2, 1), g)
    for c in range(3, g.shape[-1]):
        empty = nmat[:, c, c] <= 0.0
        nmat[empty, c, c] = 1.0
    ninv = np.linalg.inv(nmat + 1e-12 * np.eye(g.shape[-1])[None])
    return np.matmul(ninv, np.matmul(gw.transpose(0, 2, 1), y[..., None]))[..., 0], ninv


def float_solution(g, use, carrier_err_m, amb_err_m, s2_m2, sig_phi2_m2):
    """The float solution's error θ_f (n, p), its covariance (GᵀW_fG)⁻¹ (n, p, p) and weights W_f (n, k).

    y = Φ − λÑ has error e_Φ − a; weights 1/(s² + σ²_φ) on the satellites in ``use`` (module docstring, item 1).
    """
    w_f = np.where(use, 1.0 / (s2_m2 + sig_phi2_m2), 0.0)
    theta, cov = _solve(g, w_f, np.where(use, carrier_err_m - amb_err_m, 0.0))
    return theta, cov, w_f


def _dd_matrix(sel: np.ndarray, sys_idx: np.ndarray, el: np.ndarray) -> np.ndarray:
    """Double-difference operator (m − n_sys, m) over the satellites ``sel`` (indices), reference = highest of each
    system; a system with one satellite gives no row."""
    rows = []
    m = len(sel)
    for s in np.unique(sys_idx[sel]):
        members = np.flatnonzero(sys_idx[sel] == s)
        if members.size < 2:
            continue
        ref = members[np.argmax(el[sel[members]])]
        for j in members:
            if j != ref:
                r = np.zeros(m)
                r[j], r[ref] = 1.0, -1.0
                rows.append(r)
    return np.array(rows).reshape(-1, m)


def _fixed_solution(g_i, y_i, w_i, chi2_tab, pfa_tab_len, min_sats):
    """Fixed solution on the held satellites with outlier dropping; returns (θ, cov, residuals, kept mask) or None."""
    keep = w_i > 0
    while True:
        n_keep = int(keep.sum())
        if n_keep < min_sats:
            return None
        gk, yk, wk = g_i[keep], y_i[keep], w_i[keep]
        cols = [0, 1, 2] + [c for c in range(3, g_i.shape[1]) if gk[:, c].any()]
        gk = gk[:, cols]
        nmat = (gk * wk[:, None]).T @ gk
        try:
            cov = np.linalg.inv(nmat)
        except np.linalg.LinAlgError:
            return None
        theta = cov @ ((gk * wk[:, None]).T @ yk)
        r = yk - gk @ theta
        dof = n_keep - len(cols)
        t = float((wk * r * r).sum())
        if dof < 1 or t <= chi2_tab[min(dof, pfa_tab_len - 1)]:
            full = np.zeros(g_i.shape[1])
            full[cols] = theta
            res = np.zeros(len(w_i))
            res[keep] = r
            return full, cov[:3, :3], res, keep, t / max(dof, 1)
        worst = np.flatnonzero(keep)[np.argmax(wk * r * r)]
        keep[worst] = False


def rtk_engine(g: np.ndarray, used: np.ndarray, lock_s: np.ndarray, cn0_mask_ok: np.ndarray, el: np.ndarray,
               sys_idx: np.ndarray, carrier_err_m: np.ndarray, amb_err_m: np.ndarray, s2_m2: np.ndarray,
               theta_float: np.ndarray, cov_float: np.ndarray, ok: np.ndarray, wavelength_m: float,
               theta_code: np.ndarray, cov_code: np.ndarray, dt_s: float, cfg: RtkConfig = RtkConfig()) -> RtkResult:
    """Run the engine over the epochs (module docstring, items 2–3).

    Parameters
    ----------
    g : (n, k, p) design rows [−u_E, −u_N, −u_U, clocks...]; used, cn0_mask_ok : (n, k) bool (in the solution;
        C/N0 above the SNR mask); lock_s : (n, k) seconds of continuous phase lock; el : (n, k) rad
    sys_idx : (k,) system of each satellite; carrier_err_m, amb_err_m, s2_m2 : (n, k) carrier error, ambiguity
        prior error a and the receiver's prior variance s² (item 1)
    theta_float, cov_float : (n, p), (n, p, p) the float solution's error and covariance; ok : (n,) solvable
    theta_code, cov_code : (n, p), (n, p, p) the code solution's error and covariance (the position-jump check)
    dt_s : epoch interval, s
    """
    n, k, _ = g.shape
    lam = wavelength_m
    sig_phi2 = carrier_model_var_m2(el, cfg)
    w_phi = 1.0 / sig_phi2
    a_gain = s2_m2 / (s2_m2 + sig_phi2)
    w_f = np.where(used, 1.0 / (s2_m2 + sig_phi2), 0.0)
    e_y = carrier_err_m - amb_err_m
    resid_f = e_y - np.matmul(g, theta_float[..., None])[..., 0]
    e_n = amb_err_m + a_gain * resid_f
    locked = used & (lock_s >= cfg.phase_lock_s)
    ar_ok = locked & (el >= np.radians(cfg.ar_mask_deg)) & cn0_mask_ok
    restart = np.zeros((n, k), bool)
    restart[1:] = lock_s[1:] < lock_s[:-1]
    chi_val = chi2.ppf(1.0 - cfg.validation_pfa, np.arange(1, 61))
    chi_val = np.concatenate([[np.inf], chi_val])
    chi3 = float(chi2.ppf(1.0 - cfg.float_check_pfa, 3))

    fixed = np.zeros(n, bool)
    err_fix = np.full((n, 3), np.nan)
    cov_fix = np.full((n, 3, 3), np.nan)
    var_fix = np.full(n, np.nan)
    rms_fix = np.full(n, np.nan)
    wrong = np.zeros(n, bool)
    ratio = np.full(n, np.nan)
    p_s = np.full(n, np.nan)
    held = np.full(k, np.nan)          # integer error of each held ambiguity (NaN: not held)
    every = max(1, int(round(cfg.revalidate_s / dt_s)))
    sys_masks = [sys_idx == s for s in np.unique(sys_idx)]
    for i in range(n):
        held[restart[i] | ~locked[i]] = np.nan
        if not ok[i]:
            held[:] = np.nan
            continue
        sol = None
        if np.isfinite(held).any():
            h = np.isfinite(held)
            y = np.where(h, carrier_err_m[i] - lam * np.nan_to_num(held), 0.0)
            sol = _fixed_solution(g[i], y, np.where(h, w_phi[i], 0.0), chi_val, len(chi_val), cfg.hold_min_sats)
            if sol is not None:
                held[h & ~sol[3]] = np.nan          # phase outliers: their ambiguities reset
                d = sol[0][:3] - theta_code[i, :3]
                try:
                    t_f = float(d @ np.linalg.solve(cov_code[i, :3, :3], d))
                except np.linalg.LinAlgError:
                    t_f = np.inf
                if t_f > chi3:
                    sol = None
            if sol is None:
                held[:] = np.nan
            elif i % every == 0:
                trial = held.copy()
                fresh = _attempt(i, g, ar_ok, el, sys_idx, e_n, s2_m2, sig_phi2, a_gain, w_f, cov_float, resid_f,
                                 carrier_err_m, w_phi, lam, trial, cfg, chi_val, ratio, p_s)
                if fresh is not None and np.linalg.norm(fresh[0][:3] - sol[0][:3]) > cfg.revalidate_shift_m:
                    held[:] = trial
                    sol = fresh
        if sol is None:
            sol = _attempt(i, g, ar_ok, el, sys_idx, e_n, s2_m2, sig_phi2, a_gain, w_f, cov_float, resid_f,
                           carrier_err_m, w_phi, lam, held, cfg, chi_val, ratio, p_s)
        if sol is None:
            continue
        # Newly locked satellites join the held set with the integer the fixed position gives them.
        join = ar_ok[i] & ~np.isfinite(held)
        if join.any():
            x = (carrier_err_m[i, join] - g[i, join] @ sol[0]) / lam
            c = np.rint(x)
            good = np.abs(x - c) < cfg.join_max_frac_cycles
            idx = np.flatnonzero(join)[good]
            held[idx] = c[good]
        fixed[i] = True
        err_fix[i] = sol[0][:3]
        cov_fix[i], var_fix[i] = sol[1], sol[4]
        rms_fix[i] = float(np.sqrt(np.mean(sol[2][sol[3]] ** 2))) if sol[3].any() else np.nan
        # Right integers differ from the truth by one common integer per system (the clock takes it).
        for s_mask in sys_masks:
            v = held[s_mask]
            v = v[np.isfinite(v)]
            if v.size and v.min() != v.max():
                wrong[i] = True
    return RtkResult(fixed, err_fix, gst_fields(cov_fix, var_fix, rms_fix), wrong, ratio, p_s)


def _attempt(i, g, ar_ok, el, sys_idx, e_n, s2, sig_phi2, a_gain, w_f, cov_float, resid_f, carrier_err, w_phi, lam,
             held, cfg, chi_val, ratio, p_s):
    """One epoch's ambiguity resolution (item 2); on success fills ``held`` and returns the fixed solution."""
    sel = np.flatnonzero(ar_ok[i])
    norm = np.abs(resid_f[i]) * np.sqrt(w_f[i])
    for _ in range(cfg.ar_max_drops + 1):
        if sel.size < cfg.min_sats:
            return None
        dmat = _dd_matrix(sel, sys_idx, el[i])
        if dmat.shape[0] < 3:
            return None
        u = a_gain[i, sel, None] * g[i, sel]
        q_n = np.diag(1.0 / (1.0 / sig_phi2[i, sel] + 1.0 / s2[i, sel])) + u @ cov_float[i] @ u.T
        q_dd = dmat @ q_n @ dmat.T / lam ** 2
        f = dmat @ e_n[i, sel] / lam
        try:
            res = lambda_search(f, 0.5 * (q_dd + q_dd.T))
        except np.linalg.LinAlgError:
            return None
        ratio[i] = res.ratio
        p_s[i] = bootstrap_success_rate(res.d)
        if res.ratio >= cfg.ratio_threshold and p_s[i] >= cfg.min_success_rate:
            # Undifferenced integer errors: 0 on each reference, the DD integer on the others (clocks absorb the rest).
            c = np.zeros(sel.size)
            for r, v in zip(dmat, res.best):
                c[np.flatnonzero(r > 0)[0]] = v
            y = np.zeros(g.shape[1])
            w = np.zeros(g.shape[1])
            y[sel] = carrier_err[i, sel] - lam * c
            w[sel] = w_phi[i, sel]
            sol = _fixed_solution(g[i], y, w, chi_val, len(chi_val), cfg.hold_min_sats)
            if sol is None:
                return None
            held[:] = np.nan
            held[sel] = np.where(sol[3][sel], c, np.nan)
            return sol
        sel = np.delete(sel, np.argmax(norm[sel]))
    return None
