"""Access points and the radio propagation model: log-distance path loss, wall attenuation, spatially
correlated shadowing, body loss, per-reading noise, a soft detection floor and device RSS models."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rmbuild.config.simulate import RadioConfig
from rmbuild.synthetic.geometry import wall_loss_from_point
from rmbuild.synthetic.venue import Venue

CHANNELS_24_MHZ = (2412, 2437, 2462)
CHANNELS_5_MHZ = (5180, 5200, 5220, 5240, 5260, 5280, 5300, 5320, 5500, 5520, 5560, 5600, 5660,
                  5745, 5765, 5785, 5805, 5825)
SSIDS = ("rmb-guest", "rmb-staff")
_SHADOW_BAND_CORR = 0.7  # correlation of the 2.4 and 5 GHz shadowing of one AP
_SSID_NOISE_CORR = 0.7  # correlation of the reading noise of two BSSIDs of one radio


@dataclass
class RadioModel:
    """The true radio field. Radios are (AP, band) pairs; BSSIDs map onto radios (virtual SSIDs share
    their radio's field). Positions in m (building frame), powers in dBm, losses in dB.

    ``shadow_omega``: (R, F, 2) rad/m, ``shadow_phase``: (R, F), ``shadow_weight``: (R, F) random Fourier
    features of each radio's shadowing, already scaled so the field's sigma is ``shadow_sigma_db``.
    """

    ap_xy: np.ndarray  # (A, 2) physical AP positions
    radio_ap: np.ndarray  # (R,) physical AP index of each radio
    radio_band: np.ndarray  # (R,) "2.4" / "5"
    radio_freq_mhz: np.ndarray  # (R,) channel centre frequency
    radio_tx_dbm: np.ndarray  # (R,) mean RSSI at 1 m
    radio_n: np.ndarray  # (R,) path-loss exponent
    radio_wall_factor: np.ndarray  # (R,) multiplier of wall attenuation
    shadow_omega: np.ndarray
    shadow_phase: np.ndarray
    shadow_weight: np.ndarray
    bssid: np.ndarray  # (B,) str
    bssid_radio: np.ndarray  # (B,) radio index
    bssid_ssid: np.ndarray  # (B,) str
    walls: np.ndarray  # (m, 4)
    wall_atten_db: np.ndarray  # (m,)

    @property
    def radio_xy(self) -> np.ndarray:
        return self.ap_xy[self.radio_ap]

    def truth_table(self) -> pd.DataFrame:
        """truth_aps: bssid, x_m, y_m, tx_power_dbm, path_loss_exp, band (one row per BSSID)."""
        r = self.bssid_radio
        xy = self.radio_xy[r]
        return pd.DataFrame({
            "bssid": self.bssid.astype(str),
            "x_m": xy[:, 0],
            "y_m": xy[:, 1],
            "tx_power_dbm": self.radio_tx_dbm[r],
            "path_loss_exp": self.radio_n[r],
            "band": self.radio_band[r].astype(str),
        })

    def shadow_db(self, xy: np.ndarray, radios: np.ndarray) -> np.ndarray:
        """(n, len(radios)) static shadowing in dB (float32 arithmetic: ample for dB)."""
        xy32 = np.asarray(xy, dtype=np.float32)
        out = np.empty((len(xy), len(radios)))
        for j, r in enumerate(radios):
            arg = xy32 @ self.shadow_omega[r].T.astype(np.float32) + self.shadow_phase[r].astype(np.float32)
            out[:, j] = np.cos(arg) @ self.shadow_weight[r].astype(np.float32)
        return out

    def mean_rss_radios(
        self, xy: np.ndarray, radios: np.ndarray | None = None, cull_below_dbm: float | None = None
    ) -> np.ndarray:
        """(n, len(radios)) noise-free mean RSSI in dBm of the given radios (default: all) at ``xy`` (n, 2).

        With ``cull_below_dbm``, positions where a radio's wall-free, shadow-free RSSI is already below that
        level get -inf instead of a value: such readings can never be detected, and skipping their wall
        count is what keeps large venues fast.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        radios = np.arange(len(self.radio_ap)) if radios is None else np.asarray(radios, dtype=np.int64)
        out = np.full((len(xy), len(radios)), -np.inf)
        for a in np.unique(self.radio_ap[radios]):
            cols = np.flatnonzero(self.radio_ap[radios] == a)
            rr = radios[cols]
            d = np.maximum(np.hypot(xy[:, 0] - self.ap_xy[a, 0], xy[:, 1] - self.ap_xy[a, 1]), 1.0)
            free = self.radio_tx_dbm[rr][None, :] - 10.0 * self.radio_n[rr][None, :] * np.log10(d)[:, None]
            if cull_below_dbm is None:
                rows = np.arange(len(xy))
            else:
                rows = np.flatnonzero(free.max(axis=1) >= cull_below_dbm)
            if len(rows) == 0:
                continue
            loss = wall_loss_from_point(self.ap_xy[a], xy[rows], self.walls, self.wall_atten_db)
            val = free[rows] - loss[:, None] * self.radio_wall_factor[rr][None, :]
            val += self.shadow_db(xy[rows], rr)
            out[np.ix_(rows, cols)] = val
        return out


def _unique_macs(n: int, rng: np.random.Generator) -> list[int]:
    """n distinct 48-bit base addresses whose last byte is free for radio/SSID numbering."""
    seen: dict[int, None] = {}
    ouis = [0x00_1A_1E, 0x24_DE_C6, 0x70_3A_0E, 0xF4_2E_7F, 0x9C_1C_12]  # a few vendor prefixes
    while len(seen) < n:
        oui = ouis[int(rng.integers(len(ouis)))]
        mid = int(rng.integers(0, 2**16))
        seen.setdefault((oui << 24) | (mid << 8), None)
    return list(seen)


def _mac_str(v: int) -> str:
    return ":".join(f"{(v >> s) & 0xFF:02x}" for s in range(40, -1, -8))


def build_radio(cfg: RadioConfig, venue: Venue, rng: np.random.Generator) -> RadioModel:
    """Place APs (rejection sampling with a minimum spacing, outside kiosks) and draw their radios."""
    pts: list[tuple[float, float]] = []
    spacing = cfg.min_ap_spacing_m
    tries = 0
    while len(pts) < cfg.n_aps:
        tries += 1
        if tries > 200 * cfg.n_aps:  # venue too small for the spacing: relax it
            spacing *= 0.8
            tries = 0
        x = rng.uniform(1.0, venue.width_m - 1.0)
        y = rng.uniform(1.0, venue.height_m - 1.0)
        if any(k[0] - 0.5 < x < k[2] + 0.5 and k[1] - 0.5 < y < k[3] + 0.5 for k in venue.kiosks):
            continue
        if pts and np.min(np.hypot(np.array(pts)[:, 0] - x, np.array(pts)[:, 1] - y)) < spacing:
            continue
        pts.append((float(x), float(y)))
    ap_xy = np.array(pts)
    F = cfg.n_shadow_features
    scale = cfg.shadow_sigma_db * np.sqrt(2.0 / F)
    radio_ap, band, freq, tx, pl, wf, om, ph, wt = [], [], [], [], [], [], [], [], []
    for a in range(cfg.n_aps):
        omega = rng.normal(0.0, 1.0 / cfg.shadow_corr_m, size=(F, 2))
        phase = rng.uniform(0.0, 2 * np.pi, size=F)
        w24 = rng.standard_normal(F)
        n_exp = rng.uniform(*cfg.path_loss_exp)
        radio_ap.append(a)
        band.append("2.4")
        freq.append(CHANNELS_24_MHZ[int(rng.integers(len(CHANNELS_24_MHZ)))])
        tx.append(rng.uniform(*cfg.tx_power_24_dbm))
        pl.append(n_exp)
        wf.append(1.0)
        om.append(omega)
        ph.append(phase)
        wt.append(w24 * scale)
        if rng.random() < cfg.dual_band_fraction:
            w5 = _SHADOW_BAND_CORR * w24 + np.sqrt(1 - _SHADOW_BAND_CORR**2) * rng.standard_normal(F)
            radio_ap.append(a)
            band.append("5")
            freq.append(CHANNELS_5_MHZ[int(rng.integers(len(CHANNELS_5_MHZ)))])
            tx.append(rng.uniform(*cfg.tx_power_5_dbm))
            pl.append(min(n_exp + rng.uniform(0.0, 0.3), cfg.path_loss_exp[1] + 0.3))
            wf.append(cfg.wall_factor_5ghz)
            om.append(omega)
            ph.append(phase)
            wt.append(w5 * scale)
    bases = _unique_macs(cfg.n_aps, rng)
    bssid, b_radio, b_ssid = [], [], []
    radio_ap_arr = np.array(radio_ap)
    for r in range(len(radio_ap)):
        a = radio_ap[r]
        band_idx = 0 if band[r] == "2.4" else 1
        n_ssid = 2 if rng.random() < cfg.multi_ssid_fraction else 1
        for s in range(n_ssid):
            bssid.append(_mac_str(bases[a] | (0x10 * (band_idx + 1) + s)))
            b_radio.append(r)
            b_ssid.append(SSIDS[s])
    return RadioModel(
        ap_xy=ap_xy, radio_ap=radio_ap_arr, radio_band=np.array(band, dtype=object),
        radio_freq_mhz=np.array(freq, dtype=np.float64), radio_tx_dbm=np.array(tx), radio_n=np.array(pl),
        radio_wall_factor=np.array(wf), shadow_omega=np.array(om), shadow_phase=np.array(ph),
        shadow_weight=np.array(wt), bssid=np.array(bssid, dtype=object), bssid_radio=np.array(b_radio),
        bssid_ssid=np.array(b_ssid, dtype=object), walls=venue.walls, wall_atten_db=venue.wall_atten_db,
    )


def scan_cull_level(cfg: RadioConfig) -> float:
    """dBm; a mean RSSI (reference device) below this can never give a detected reading."""
    return (cfg.detect_floor_dbm - 3 * cfg.shadow_sigma_db - 5 * cfg.noise_sigma_db
            - 4 * cfg.walk_offset_sigma_db - cfg.body_loss_db - 10.0)


def scan_readings(
    model: RadioModel,
    cfg: RadioConfig,
    mean_start: np.ndarray,
    mean_end: np.ndarray,
    xy_end: np.ndarray,
    heading: np.ndarray,
    k: float,
    b: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Readings of the scans of one walk, in time order. A scan sweeps from where the radios' mean RSSI
    is ``mean_start`` to where it is ``mean_end`` (S, R) dBm (-inf = out of range); each reading is taken
    at a random point of the sweep. ``xy_end`` (S, 2) m and ``heading`` (S,) rad give the body loss; the
    device model is RSS = k phi + b. Returns (scan index, BSSID index, RSSI dBm as integer-valued float)
    of the reported readings, ordered by scan then BSSID."""
    S = len(xy_end)
    n_b = len(model.bssid)
    if S == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    r_idx = model.bssid_radio
    u = rng.random((S, n_b))  # when in the sweep each BSSID is heard
    m0, m1 = mean_start[:, r_idx], mean_end[:, r_idx]
    with np.errstate(invalid="ignore"):
        mean_b = np.where(np.isfinite(m0) & np.isfinite(m1), (1.0 - u) * m0 + u * m1, -np.inf)
    rxy = model.radio_xy
    to_ap = rxy[None, :, :] - xy_end[:, None, :]
    ang = np.arctan2(to_ap[..., 1], to_ap[..., 0]) - heading[:, None]
    body = cfg.body_loss_db * 0.5 * (1.0 - np.cos(ang))  # AP behind the walker: full body loss
    offset = cfg.walk_offset_sigma_db * rng.standard_normal(len(model.radio_ap))[None, :]
    noise_r = rng.standard_normal((S, len(model.radio_ap)))
    noise_b = rng.standard_normal((S, n_b))
    noise = cfg.noise_sigma_db * (np.sqrt(_SSID_NOISE_CORR) * noise_r[:, r_idx]
                                  + np.sqrt(1 - _SSID_NOISE_CORR) * noise_b)
    phi = mean_b + (offset - body)[:, r_idx] + noise
    with np.errstate(invalid="ignore"):
        rssi = np.minimum(np.round(k * phi + b), -1.0)
        p_det = (1.0 - cfg.miss_prob) / (1.0 + np.exp(-(rssi - cfg.detect_mid_dbm) / cfg.detect_soft_db))
    det = np.isfinite(rssi) & (rssi >= cfg.detect_floor_dbm) & (rng.random((S, n_b)) < p_det)
    # stale cache entries: the previous scan's entry (reading or absence) is reported again
    stale = rng.random((S, n_b)) < cfg.stale_prob
    for s in range(1, S):
        st = stale[s]
        det[s, st] = det[s - 1, st]
        rssi[s, st] = rssi[s - 1, st]
    si, bi = np.nonzero(det)
    return si, bi, rssi[si, bi]
