"""SLAC: simultaneous localization and calibration (He et al. 2015).

Per test walk, scans in time order. For each new scan the last ``M`` scans (the window) are localized
jointly for every particle ``p`` = device model ``[k_p, b_p]``:

* **signal difference** (eq. 9-10): with the scan mapped into map units, ``u = k'φ + b'``, and the RP's
  mean ψ̄ and std σ per AP, ``Γ_p(φ_m, ψ_q) = mean over shared APs of (u − ψ̄)² + σ²`` (APs not detected
  on either side excluded; an RP sharing no AP is never a candidate). Under ``device_model = "device"``
  the particle is the device's own model ``φ = kψ + b`` and ``k' = 1/k, b' = −b/k``; under
  ``"calibration"`` it is eq. 5 literally (``k' = k, b' = b``). Γ for all RPs comes from six matrix products
  per scan (expand the square), so it costs O(Q·L) per scan, not per particle.
* **candidates**: the ``N`` RPs with the smallest Γ; ``λ = max Γ / Σ Γ`` over them (eq. 14).
* **joint optimisation** (eq. 11-20): weights ``ω`` (window × N per particle) on the capped simplex
  (Σω = 1, 0 ≤ ω ≤ λ) with the signal bound ``Σ_m Σ_q Γω ≤ γ`` and the shared step model ``[α, β]``,
  minimising ``Σ_m B(‖x_m − x_{m−1}‖ − δ_m)`` (Berhu, eq. 17), ``x_m = Σ ω r``, ``δ_m = Σ_c (α f_c + β)``
  over the steps between the two scans. ``γ = g Σ_m c_m`` with ``c_m`` the least signal cost reachable
  under the cap (He et al. 2015 writes ``g Σ min Γ``, which the cap makes unreachable for g near 1).
  Solved for all particles at once by projected gradient (exact projection onto the capped simplex by
  its breakpoints) with a feasibility retraction towards the least-signal-cost point for the signal bound;
  ``[α, β]`` by projected gradient on their box. The Berhu loss and the norm get an ``ε`` smoothing at 0.
* **particle filter** (eq. 21-25): ``θ_p ∝ exp(−(Σδ − Σd_p)² / 2σ_w²)`` (optionally times the Gaussian
  likelihood of the newest scan given the particle's weighted RPs, ``particle_weight``), estimate
  ``x̂ = Σ θ_p x_p``, ``k̂, b̂ = Σ θ_p [k_p, b_p]``, systematic resampling, roughening.
* **convergence** (eq. 26-29): ``ξ = mean_p ‖x_p − x̂‖ ≤ η sqrt(Var δ)``, ``Var δ = C (α² Var f + β²)``;
  then ``P = 1`` with ``[k̂, b̂, α, β]`` fixed for the rest of the walk.

Fallbacks (named in :attr:`SlacLocalizer.diagnostics` and :meth:`SlacLocalizer.summary`):
``"std:median"`` / ``"std:zero"`` (σ missing in the map), ``"steps:pdr"`` (no step frequencies),
``"steps:none"`` (no step events, ``no_steps = "fingerprint_only"``), ``"window:short"`` (the walk has
fewer scans than M: the window never fills), ``"scan:no_shared_ap"`` (a scan shares no AP with any RP:
NaN, its steps carry over to the next scan).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pandas as pd

from rmbuild.baselines.calibration import to_map_units
from rmbuild.baselines.config import SlacConfig
from rmbuild.blas import one_blas_thread
from rmbuild.errors import InputError
from rmbuild.localize.base import Query, ReferenceSet, as_reference, checked, sub_config

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- numeric kernels
def berhu(z: np.ndarray, t: float) -> np.ndarray:
    """Berhu loss (eq. 17): |z| for |z| <= T, (z² + T²) / 2T beyond."""
    a = np.abs(z)
    return np.where(a <= t, a, (z * z + t * t) / (2.0 * t))


def project_capped_simplex(y: np.ndarray, cap: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Euclidean projection of each row of ``y`` (..., N) onto {Σω = 1, 0 ≤ ω ≤ cap, ω = 0 where not valid}.

    ``cap`` (...,) per row with cap · (valid entries) >= 1. See :class:`CappedSimplexProjection`."""
    return CappedSimplexProjection(cap, valid)(y)


class CappedSimplexProjection:
    """Projection onto the capped simplex of fixed ``cap`` (...,) and ``valid`` (..., N), for many ``y``.

    Exact: ω = clip(y − τ, 0, cap) where the row sum s(τ) = Σ relu(y − τ) − relu(y − cap − τ) crosses 1.
    s is piecewise linear with breakpoints y and y − cap; sorted in descending order (v_m with signs ±1),
    s(v_m) = Σ_{j<m} sign_j v_j − v_m Σ_{j<m} sign_j comes from two cumulative sums, and τ is interpolated
    between the breakpoints around the crossing (2.5x faster than evaluating s at every breakpoint by
    broadcasting, for SLAC's 60 x 7 rows of 10). What does not depend on ``y`` is prepared once.
    """

    def __init__(self, cap: np.ndarray, valid: np.ndarray) -> None:
        self.shape = valid.shape
        n = self.n = valid.shape[-1]
        self.c = np.broadcast_to(cap, valid.shape[:-1]).reshape(-1, 1)
        self.v = valid.reshape(-1, n)
        self.invalid = ~self.v
        self.rows = np.arange(0, self.v.size * 2, 2 * n)  # flat offsets of the (R, 2N) breakpoint rows
        self.tri = np.triu(np.ones((2 * n, 2 * n)))  # cumulative sums as one product (2x np.cumsum on rows of 20)

    def __call__(self, y: np.ndarray) -> np.ndarray:
        n, c = self.n, self.c
        y2 = y.reshape(-1, n)
        lo = np.where(self.v, y2, np.inf).min(axis=1, keepdims=True)
        y2 = np.where(self.v, y2, lo - 4.0 * c - 1.0)  # invalid entries never rise above 0
        vals = np.concatenate([y2, y2 - c], axis=1)  # (R, 2N)
        o = np.argsort(-vals, axis=1)
        sg = np.where(o < n, 1.0, -1.0)
        o += self.rows[:, None]  # flat indices: plain takes, no per-call index building
        vs = vals.take(o)
        s = (sg * vs) @ self.tri
        s -= vs * (sg @ self.tri)  # s(v_m), non-decreasing in m
        j = np.minimum(np.maximum((s < 1.0).sum(axis=1), 1), 2 * n - 1)  # s[j-1] < 1 <= s[j]
        j += self.rows
        b0, b1, s0, s1 = vs.take(j - 1), vs.take(j), s.take(j - 1), s.take(j)
        den = s1 - s0
        ok = den > 1e-15
        tau = np.where(ok, b0 + (1.0 - s0) * (b1 - b0) / np.where(ok, den, 1.0), b1)
        w = np.minimum(np.maximum(y2 - tau[:, None], 0.0), c)
        w[self.invalid] = 0.0
        w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-300)  # rounding only
        return w.reshape(self.shape)


def greedy_capped(gam: np.ndarray, cap: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Least-cost point of the capped simplex: fill ``cap`` on the smallest ``gam`` first (rows sorted
    ascending along the last axis, invalid entries last). Returns ω (..., N)."""
    c = cap[..., None]
    before = np.cumsum(np.where(valid, c, 0.0), axis=-1) - c
    w = np.clip(1.0 - before, 0.0, c)
    return np.where(valid, w, 0.0)


# --------------------------------------------------------------------------- results
@dataclass
class SlacWalkResult:
    """What SLAC learnt on one walk. ``xi_m`` (n_scans,) dispersion ξ after each scan (NaN before the first
    estimate, 0 after convergence); ``converged_scan``: index (within the walk's scans, time order) of the
    scan at which ξ <= η sqrt(Var δ) first held, or None; ``k, b`` in the config's ``device_model``
    direction; ``alpha`` m/Hz, ``beta`` m (NaN when not calibrated); ``fallbacks``: names of fallbacks."""

    walk_id: str
    n_scans: int
    k: float
    b: float
    alpha: float
    beta: float
    converged_scan: int | None
    converged_t_s: float | None
    xi_m: np.ndarray
    fallbacks: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        def num(v):
            return None if v is None or not np.isfinite(v) else float(v)

        return {"walk_id": self.walk_id, "n_scans": self.n_scans, "k": num(self.k), "b": num(self.b),
                "alpha": num(self.alpha), "beta": num(self.beta), "converged_scan": self.converged_scan,
                "converged_t_s": num(self.converged_t_s), "fallbacks": list(self.fallbacks),
                "xi_final_m": num(self.xi_m[-1]) if len(self.xi_m) else None}


@dataclass
class _Steps:
    """Per scan: steps since the previous scan — count C, Σ f (Hz), Σ PDR length (m); and the frequencies."""

    count: np.ndarray
    fsum: np.ndarray
    length: np.ndarray
    freqs: list[np.ndarray]


def _steps_between(t_scan: np.ndarray, steps: pd.DataFrame) -> _Steps:
    ts = steps["t_s"].to_numpy(dtype=float)
    f = steps["step_freq_hz"].to_numpy(dtype=float)
    ln = steps["step_length_m"].to_numpy(dtype=float)
    o = np.argsort(ts, kind="stable")
    ts, f, ln = ts[o], f[o], ln[o]
    # scan i collects steps with t in (t_{i-1}, t_i]; the first scan has none before it
    hi = np.searchsorted(ts, t_scan, side="right")
    lo = np.r_[hi[0], hi[:-1]] if len(hi) else hi
    cf = np.r_[0.0, np.cumsum(np.nan_to_num(f))]
    cl = np.r_[0.0, np.cumsum(np.nan_to_num(ln))]
    count = (hi - lo).astype(float)
    return _Steps(count, cf[hi] - cf[lo], cl[hi] - cl[lo], [f[a:b] for a, b in zip(lo, hi, strict=True)])


@dataclass
class _WalkData:
    """One walk prepared for SLAC: Γ terms per scan (:meth:`SlacLocalizer._scan_terms`), detected APs, which
    scans share an AP with the map and which RPs cover each scan, the steps between scans and their sums
    carried to the next scan that shares an AP (``acc``: count, Σ f, Σ length), the step source used."""

    terms: np.ndarray
    det_scan: np.ndarray
    has_rp: np.ndarray
    coverage_ok: np.ndarray
    st: _Steps
    acc: np.ndarray
    step_source: str
    no_steps: bool
    fallbacks: list[str]


@dataclass
class _Particles:
    """SLAC's particles over one walk: device models (k_p, b_p), the shared step model (α, β), the weighted
    device estimate and the scan at which the filter converged (None before)."""

    kp: np.ndarray
    bp: np.ndarray
    alpha: float
    beta: float
    k_hat: float
    b_hat: float
    converged: int | None = None


def _carried_steps(st: _Steps, has_rp: np.ndarray) -> np.ndarray:
    """(3, n) step count, Σ f and Σ length since the previous scan that shares an AP with the map (the
    steps before a scan that shares none carry over to the next one; 0 at such scans)."""
    acc = np.zeros((3, len(has_rp)))
    carry = np.zeros(3)
    for i in range(len(has_rp)):
        carry += (st.count[i], st.fsum[i], st.length[i])
        if has_rp[i]:
            acc[:, i] = carry
            carry[:] = 0.0
    return acc


def _candidates(gam: np.ndarray, n_candidates: int) -> tuple[np.ndarray, ...]:
    """The N RPs of least Γ per particle and window scan, in order of Γ: (cand, Γ, Γ with 0 where
    invalid, valid, λ = max Γ / Σ Γ (eq. 14) raised to 1/|valid| so that the capped simplex is feasible)."""
    n_c = min(n_candidates, gam.shape[2])
    part = np.argpartition(gam, n_c - 1, axis=2)[..., :n_c] if n_c < gam.shape[2] else \
        np.broadcast_to(np.arange(gam.shape[2]), gam.shape[:2] + (gam.shape[2],)).copy()
    gc = np.take_along_axis(gam, part, axis=2)
    o = np.argsort(gc, axis=2)
    cand = np.take_along_axis(part, o, axis=2)
    gc = np.take_along_axis(gc, o, axis=2)
    valid = np.isfinite(gc)
    nv = valid.sum(axis=2)
    gz = np.where(valid, gc, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = gz.max(axis=2) / gz.sum(axis=2)
    lam = np.where(np.isfinite(lam), lam, 1.0)
    lam = np.maximum(lam, 1.0 / np.maximum(nv, 1))
    return cand, gc, gz, valid, lam


class SlacLocalizer:
    """SLAC (He et al. 2015). ``fit(radio_map)``, then ``predict(query)`` needs ``query.steps`` for each walk.

    After ``predict``, :attr:`diagnostics` maps walk id -> :class:`SlacWalkResult`.
    """

    name: ClassVar[str] = "slac"

    def __init__(self, cfg: SlacConfig | None = None) -> None:
        self.cfg = checked(cfg, SlacConfig)
        self.ref: ReferenceSet | None = None
        self.diagnostics: dict[str, SlacWalkResult] = {}
        self.map_fallbacks: list[str] = []

    @classmethod
    def from_config(cls, cfg) -> SlacLocalizer:
        return cls(sub_config(cfg, "slac", SlacConfig))

    # ------------------------------------------------------------------ fit
    def fit(self, ref) -> SlacLocalizer:
        """Store the RPs (a RadioMap's cells, or a ReferenceSet) with their per-AP mean and std."""
        ref = as_reference(ref, "cells")
        if len(ref) == 0:
            raise InputError("SLAC: the reference set is empty")
        self.ref = ref
        det = ~np.isnan(ref.rss_dbm)
        self.map_fallbacks = []
        std = None if ref.std_db is None else np.asarray(ref.std_db, dtype=np.float64)
        has_std = std is not None and bool(np.isfinite(std[det]).any())
        if not has_std and self.cfg.missing_std == "error":
            raise InputError("SLAC: the map has no RSSI std (σ); set slac.missing_std to 'median' or 'zero'")
        if std is None:
            std = np.full(det.shape, np.nan)
        miss = det & ~np.isfinite(std)
        fill = 0.0
        if miss.any():
            if self.cfg.missing_std == "median" and has_std:
                fill = float(np.median(std[det & np.isfinite(std)]))
                self.map_fallbacks.append("std:median")
            else:
                self.map_fallbacks.append("std:zero")
        std = np.where(miss, fill, np.nan_to_num(std))
        psi = np.where(det, ref.rss_dbm.astype(np.float64), 0.0)
        self._B = det.astype(np.float64)  # (Q, L)
        self._Psi = psi
        self._S2 = np.where(det, psi * psi + std * std, 0.0)
        self._xy = np.asarray(ref.xy, dtype=np.float64)
        self.std_fill_db = fill
        return self

    # ------------------------------------------------------------- signals
    def _scan_terms(self, rss: np.ndarray, ok: np.ndarray | None = None) -> np.ndarray:
        """(6, n, Q) sums over shared APs: Σφ², Σφ, |S|, Σφψ̄, Σψ̄, Σ(ψ̄² + σ²). With ``ok`` (n, Q), all
        but |S| only where ok (0 elsewhere), each scan's over its own detected APs (a scan hears ~1/10 of
        them, and an RP covers few scans)."""
        det = ~np.isnan(rss)
        phi = np.where(det, rss.astype(np.float64), 0.0)
        b = det.astype(np.float64)
        if ok is None:
            t1 = np.stack([phi * phi, phi, b]) @ self._B.T  # (3, n, Q)
            return np.concatenate([t1, (phi @ self._Psi.T)[None], (b @ self._Psi.T)[None],
                                   (b @ self._S2.T)[None]])
        out = np.zeros((6,) + ok.shape)
        out[2] = b @ self._B.T
        for i in range(len(rss)):
            q, j = np.flatnonzero(ok[i]), np.flatnonzero(det[i])
            if not len(q):
                continue
            sub = np.ix_(q, j)
            bq, pq, f = self._B[sub], self._Psi[sub], phi[i, j]
            out[0, i, q], out[1, i, q], out[3, i, q] = bq @ (f * f), bq @ f, pq @ f
            out[4, i, q], out[5, i, q] = pq.sum(axis=1), self._S2[sub].sum(axis=1)
        return out

    @staticmethod
    def _gamma(terms: np.ndarray, kp: np.ndarray, bp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Γ (P, W, Q) for map-unit parameters kp, bp (P,) and scan terms (6, W, Q); inf where |S| = 0.
        Also |S| (W, Q). The numerator is one matrix product of the (P, 6) polynomial coefficients in k, b."""
        a3 = terms[2]
        coef = np.stack([kp * kp, 2 * kp * bp, bp * bp, -2 * kp, -2 * bp, np.ones_like(kp)], axis=1)
        num = (coef @ terms.reshape(6, -1)).reshape((len(kp),) + a3.shape)
        np.maximum(num, 0.0, out=num)
        with np.errstate(divide="ignore", invalid="ignore"):
            num /= np.where(a3 > 0, a3, 1.0)
        num[:, a3 <= 0] = np.inf
        return num, a3

    def _detection_ll(self, cand: np.ndarray, det: np.ndarray, kk: np.ndarray, bb: np.ndarray) -> np.ndarray:
        """(P, N) log-probability of which of each candidate RP's APs the scan detected (ours): an AP the
        RP hears at ψ̄ reads φ = (ψ̄ − b') / k' on the device and is detected with probability
        (1 − miss_prob) Φ((φ − floor) / s), s = signal_sigma_db / k'."""
        cfg = self.cfg
        from scipy.special import ndtr

        aps = np.flatnonzero(self._B[np.unique(cand)].any(axis=0))  # only APs some candidate hears count
        psi = self._Psi[cand[..., None], aps]  # (P, N, A)
        rp_det = self._B[cand[..., None], aps] > 0
        k = np.abs(kk)[:, None, None]
        pred = (psi - bb[:, None, None]) / k
        p = (1.0 - cfg.miss_prob) * ndtr((pred - cfg.detect_floor_dbm) * k / cfg.signal_sigma_db)
        p = np.clip(p, 1e-6, 1.0 - 1e-6)
        ll = np.where(det[aps], np.log(p), np.log1p(-p))
        return np.where(rp_det, ll, 0.0).sum(axis=2)

    # ------------------------------------------------------------- solver
    def _solve(self, gam_c, valid, cap, r_c, f_sum, count, dist_pdr, alpha, beta, theta, fixed_ab):
        """Joint optimisation (eq. 20) for all particles. Shapes: gam_c, valid, r_c[..., :] (P, W, N[, 2]),
        cap (P, W); f_sum, count, dist_pdr (W,) steps before each window scan (index 0 unused).
        Returns ω (P, W, N), α, β."""
        cfg = self.cfg
        t, eps = cfg.berhu_t_m, cfg.solver_eps_m
        w0 = greedy_capped(gam_c, cap, valid)
        gcost = np.where(valid, gam_c, 0.0)
        cost0 = (gcost * w0).sum(axis=(1, 2))
        gamma = cfg.g * cost0
        n_w = gam_c.shape[1]
        if n_w < 2:
            return w0, alpha, beta
        rc = r_c - (r_c * valid[..., None]).sum(axis=2, keepdims=True) / np.maximum(
            valid.sum(axis=2, keepdims=True), 1)[..., None]
        spread2 = (np.where(valid, (rc * rc).sum(axis=3), 0.0)).max(axis=2)  # (P, W)
        eta = 0.5 * t / (4.0 * spread2 + 1.0)
        fs, cn = f_sum[1:], count[1:]
        use_model = cfg.step_source == "frequency" and not fixed_ab
        lo_a, hi_a = cfg.alpha_range
        lo_b, hi_b = cfg.beta_range
        eta_a = 0.25 * t / (float((fs * fs).sum()) + 1e-9)
        eta_b = 0.25 * t / (float((cn * cn).sum()) + 1e-9)
        centre = (r_c - rc)[:, :, 0, :]  # (P, W, 2): each row's centre
        rct = np.ascontiguousarray(np.moveaxis(rc, 3, 2))  # (P, W, 2, N)
        w = w0
        project = CappedSimplexProjection(cap, valid)
        eps2 = eps * eps
        freq = cfg.step_source == "frequency"
        for it in range(cfg.solver_iters):
            x = np.einsum("pwkn,pwn->pwk", rct, w) + centre  # (P, W, 2) position of each window scan
            dx = x[:, 1:] - x[:, :-1]
            d = np.sqrt(np.einsum("pwk,pwk->pw", dx, dx) + eps2)
            z = d - ((alpha * fs + beta * cn) if freq else dist_pdr[1:])
            gz = np.where(np.abs(z) <= t, z / np.sqrt(z * z + eps2), z / t)  # (P, W-1)
            gseg = dx * (gz / d)[..., None]
            gx = np.zeros_like(x)
            gx[:, 1:] = gseg
            gx[:, :-1] -= gseg
            gw = np.einsum("pwk,pwkn->pwn", gx, rct)  # (P, W, N)
            decay = 1.0 / np.sqrt(1.0 + it / 10.0)
            w = project(w - (eta * decay)[..., None] * gw)
            # signal bound: retract towards the least-cost point when violated
            cost = np.einsum("pwn,pwn->p", gcost, w)
            over = cost > gamma
            if over.any():
                sc = np.where(over, (gamma - cost0) / np.maximum(cost - cost0, 1e-12), 1.0)
                w = w0 + sc[:, None, None] * (w - w0)
            if use_model:
                tg = theta @ gz
                alpha = min(max(alpha + eta_a * decay * float(tg @ fs), lo_a), hi_a)
                beta = min(max(beta + eta_b * decay * float(tg @ cn), lo_b), hi_b)
        return w, alpha, beta

    # ------------------------------------------------------------- predict
    def predict(self, query: Query) -> np.ndarray:
        """(n, 2) metres in the map's frame, one row per scan (causal: each from the scans up to it)."""
        if self.ref is None:
            raise RuntimeError("fit() first")
        q = query.aligned(self.ref.bssids)
        out = np.full((len(q), 2), np.nan)
        self.diagnostics = {}
        for wid, rows in q.walks():
            steps = None if q.steps is None else q.steps.get(wid)
            with one_blas_thread():
                xy, res = self.localize_walk(q.rss_dbm[rows], q.t_s[rows], steps, wid)
            out[rows] = xy
            self.diagnostics[wid] = res
        return out

    def summary(self) -> dict:
        """Medians over the last predict's walks of k, b, alpha, beta; walks converged; fallbacks used."""
        res = list(self.diagnostics.values())

        def med(key):
            v = np.array([getattr(r, key) for r in res], dtype=float)
            v = v[np.isfinite(v)]
            return float(np.median(v)) if v.size else None

        fb = sorted({f for r in res for f in r.fallbacks} | set(self.map_fallbacks))
        return {"k": med("k"), "b": med("b"), "alpha": med("alpha"), "beta": med("beta"),
                "device_model": self.cfg.device_model, "n_walks": len(res),
                "n_converged": sum(r.converged_scan is not None for r in res), "fallbacks": fb}

    def localize_walk(
        self, rss_dbm: np.ndarray, t_s: np.ndarray, steps: pd.DataFrame | None, walk_id: str = ""
    ) -> tuple[np.ndarray, SlacWalkResult]:
        """Localize one walk's scans (time order). ``rss_dbm`` (n, L) in the map's AP order, NaN = missing;
        ``t_s`` (n,) s; ``steps``: the walk's step table (t_s, step_length_m, step_freq_hz). Returns
        ((n, 2) positions, :class:`SlacWalkResult`)."""
        cfg = self.cfg
        n = len(t_s)
        rng = np.random.default_rng(cfg.seed)
        wd = self._walk_data(np.asarray(rss_dbm), np.asarray(t_s, dtype=float), steps, walk_id)
        pt = self._initial_particles(rng)
        out = np.full((n, 2), np.nan)
        xi_hist = np.full(n, np.nan)
        window: list[int] = []  # indices of valid scans in the window
        seen = 0
        for i in np.flatnonzero(wd.has_rp):
            seen += 1
            window.append(int(i))
            if len(window) > cfg.window_scans:
                window.pop(0)
            out[i], xi_hist[i] = self._scan_update(wd, pt, np.array(window), seen, rng)
        alpha, beta = pt.alpha, pt.beta
        if wd.no_steps or wd.step_source != "frequency":
            alpha, beta = float("nan"), float("nan")
        conv = pt.converged
        res = SlacWalkResult(walk_id, n, pt.k_hat, pt.b_hat, alpha, beta, conv,
                             None if conv is None else float(t_s[conv]), xi_hist, wd.fallbacks)
        return out, res

    def _walk_data(self, rss: np.ndarray, t_s: np.ndarray, steps: pd.DataFrame | None, walk_id: str) -> _WalkData:
        """One walk's inputs as SLAC uses them: the steps between scans (carried over scans that share no AP
        with the map), the scans' Γ terms and which RPs cover each scan; the fallbacks taken."""
        cfg = self.cfg
        fallbacks: list[str] = []
        no_steps = steps is None or len(steps) == 0
        if no_steps:
            if cfg.no_steps == "error":
                raise InputError(f"SLAC: walk {walk_id!r} has no step events (set slac.no_steps = "
                                 "'fingerprint_only' to localize it from Wi-Fi alone)")
            fallbacks.append("steps:none")
            steps = pd.DataFrame({"t_s": [], "step_length_m": [], "step_freq_hz": []})
        assert steps is not None
        step_source = cfg.step_source
        if not no_steps and step_source == "frequency" and not np.isfinite(
                steps["step_freq_hz"].to_numpy(dtype=float)).any():
            step_source = "pdr"
            fallbacks.append("steps:pdr")
        if len(t_s) < cfg.window_scans:
            fallbacks.append("window:short")
        st = _steps_between(t_s, steps)
        if step_source == "frequency" and not no_steps:
            fmed = float(np.nanmedian(steps["step_freq_hz"].to_numpy(dtype=float)))
            # steps with a missing frequency count at the walk's median frequency
            nan_cnt = np.array([np.isnan(f).sum() for f in st.freqs], dtype=float)
            st.fsum = st.fsum + nan_cnt * fmed
        shared = (~np.isnan(rss)).astype(np.float64) @ self._B.T  # (n, Q) APs each RP shares with each scan
        has_rp = (shared > 0).any(axis=1)  # scan shares an AP with at least one RP
        # coverage: an RP must share >= min_shared_fraction of the scan's APs (or the best any RP shares)
        n_scan_ap = (~np.isnan(rss)).sum(axis=1)
        need = np.minimum(np.ceil(cfg.min_shared_fraction * n_scan_ap - 1e-9), shared.max(axis=1))
        coverage_ok = shared >= np.maximum(need, 1.0)[:, None]
        terms = self._scan_terms(rss, coverage_ok)  # Γ is only ever needed where an RP covers the scan
        if not has_rp.all():
            fallbacks.append("scan:no_shared_ap")
        acc = _carried_steps(st, has_rp)
        return _WalkData(terms, ~np.isnan(rss), has_rp, coverage_ok, st, acc, step_source, no_steps, fallbacks)

    def _initial_particles(self, rng: np.random.Generator) -> _Particles:
        """Device models drawn uniformly over the config's ranges, the step model at its ranges' centres."""
        cfg = self.cfg
        kp = rng.uniform(cfg.k_range[0], cfg.k_range[1], cfg.n_particles)
        bp = rng.uniform(cfg.b_range_db[0], cfg.b_range_db[1], cfg.n_particles)
        return _Particles(kp, bp, float(np.mean(cfg.alpha_range)), float(np.mean(cfg.beta_range)),
                          float(np.mean(kp)), float(np.mean(bp)))

    def _scan_update(self, wd: _WalkData, pt: _Particles, win: np.ndarray, seen: int,
                     rng: np.random.Generator) -> tuple[np.ndarray, float]:
        """The window ending at a new scan, solved for every particle; the particles weighted, the estimate
        taken, then resampled and tested for convergence (or kept once converged). Returns (x̂, ξ)."""
        cfg = self.cfg
        kk, bb = to_map_units(pt.kp, pt.bp, cfg.device_model)
        kk, bb = np.atleast_1d(kk), np.atleast_1d(bb)
        ok = wd.coverage_ok[win]
        rps = np.flatnonzero(ok.any(axis=0))  # only RPs that cover a window scan can be candidates
        if len(rps) < cfg.n_candidates:
            rps = np.arange(ok.shape[1])
        gam, _ = self._gamma(wd.terms[:, win][:, :, rps], kk, bb)
        gam[:, ~ok[:, rps]] = np.inf
        cand, gc, gz, valid, lam = _candidates(gam, cfg.n_candidates)
        cand = rps[cand]
        shared = wd.terms[2][win]
        r_c = self._xy[cand]
        p_cur = gam.shape[0]
        acc_c, acc_f, acc_l = wd.acc[0][win], wd.acc[1][win], wd.acc[2][win]
        frozen = wd.no_steps or pt.converged is not None
        w, a_new, b_new = self._solve(gc, valid, lam, r_c, acc_f, acc_c, acc_l, pt.alpha, pt.beta,
                                      np.full(p_cur, 1.0 / p_cur), frozen)
        if not (frozen or wd.step_source != "frequency"):
            pt.alpha, pt.beta = a_new, b_new
        x = (w[..., None] * r_c).sum(axis=2)  # (P, W, 2)
        logw = self._particle_logw(wd, pt, win, x, w, gz, cand, shared, kk, bb)
        theta = np.exp(logw - logw.max())
        theta /= theta.sum()
        est = (theta[:, None] * x[:, -1]).sum(axis=0)
        if pt.converged is not None:
            return est, 0.0
        return est, self._resample(wd, pt, win, seen, theta, x[:, -1], est, rng)

    def _particle_logw(self, wd: _WalkData, pt: _Particles, win: np.ndarray, x: np.ndarray, w: np.ndarray,
                       gz: np.ndarray, cand: np.ndarray, shared: np.ndarray, kk: np.ndarray,
                       bb: np.ndarray) -> np.ndarray:
        """Log particle weights (eq. 21-23): the walked distance against the steps', times (under
        ``particle_weight = "distance_signal"``) the Gaussian likelihood of the newest scan given the
        particle's weighted RPs (map units, with the Jacobian k' of u = k'φ + b' per shared AP)."""
        cfg = self.cfg
        p_cur = len(x)
        acc_c, acc_f, acc_l = wd.acc[0][win], wd.acc[1][win], wd.acc[2][win]
        if len(win) >= 2 and not wd.no_steps:
            d_est = np.hypot(*np.moveaxis(np.diff(x, axis=1), 2, 0)).sum(axis=1)
            delta = acc_l[1:].sum() if wd.step_source == "pdr" else \
                float((pt.alpha * acc_f[1:] + pt.beta * acc_c[1:]).sum())
            logw = -((delta - d_est) ** 2) / (2.0 * cfg.sigma_w_m ** 2)
        else:
            logw = np.zeros(p_cur)
        if cfg.particle_weight == "distance_signal" and p_cur > 1:
            s_new = np.take_along_axis(np.broadcast_to(shared[-1], (p_cur,) + shared[-1].shape),
                                       cand[:, -1], axis=1)
            ll = -0.5 * s_new * gz[:, -1] / cfg.signal_sigma_db ** 2 + s_new * np.log(np.abs(kk))[:, None]
            if cfg.detect_floor_dbm is not None:
                ll = ll + self._detection_ll(cand[:, -1], wd.det_scan[win[-1]], kk, bb)
            logw = logw + (w[:, -1] * ll).sum(axis=1)
        return logw

    def _resample(self, wd: _WalkData, pt: _Particles, win: np.ndarray, seen: int, theta: np.ndarray,
                  x_new: np.ndarray, est: np.ndarray, rng: np.random.Generator) -> float:
        """k̂, b̂ from the weights; systematic resampling and roughening; the convergence test (eq. 26-29),
        after which one particle at [k̂, b̂] stays. Returns ξ, the particles' mean distance to x̂."""
        cfg = self.cfg
        p_cur = len(theta)
        pt.k_hat, pt.b_hat = float((theta * pt.kp).sum()), float((theta * pt.bp).sum())
        idx = np.minimum(np.searchsorted(np.cumsum(theta), (rng.random() + np.arange(p_cur)) / p_cur), p_cur - 1)
        xi = float(np.hypot(*(x_new[idx] - est).T).mean())
        pt.kp, pt.bp = pt.kp[idx], pt.bp[idx]
        if p_cur > 1 and cfg.roughen > 0:
            k_span = max(cfg.k_range[1] - cfg.k_range[0], 0.0)
            b_span = max(cfg.b_range_db[1] - cfg.b_range_db[0], 0.0)
            sk = cfg.roughen * max(np.ptp(pt.kp), 0.02 * k_span) / np.sqrt(p_cur)
            sb = cfg.roughen * max(np.ptp(pt.bp), 0.02 * b_span) / np.sqrt(p_cur)
            pt.kp = np.clip(pt.kp + rng.normal(0, sk, p_cur), *cfg.k_range)
            pt.bp = np.clip(pt.bp + rng.normal(0, sb, p_cur), *cfg.b_range_db)
        min_conv = cfg.min_scans_to_converge or cfg.window_scans
        if cfg.converge and not wd.no_steps and seen >= min_conv and p_cur > 1:
            fw = np.concatenate([wd.st.freqs[j] for j in win]) if len(win) else np.zeros(0)
            fw = fw[np.isfinite(fw)]
            var_f = float(fw.var()) if fw.size > 1 else 0.0
            var_d = wd.acc[0][win[-1]] * (pt.alpha ** 2 * var_f + pt.beta ** 2)
            if xi <= cfg.eta * np.sqrt(var_d):
                pt.converged = int(win[-1])
                pt.kp, pt.bp = np.array([pt.k_hat]), np.array([pt.b_hat])
        return xi
