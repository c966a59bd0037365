"""Sensor clocks: stray timestamps, clock jumps and dropouts, found before any signal is resampled.

A phone's IMU samples arrive with timestamps that may be wrong in ways a resampler must not trust: a single
sample stamped ``1`` or ``1e9`` s, a clock that jumps by days, or seconds without any sample. Everything that
resamples (step detection, gravity tracking) works on the *runs* found here — stretches without a gap longer
than :data:`DROPOUT_S` — so its memory follows the number of samples, never the span of the clock.

Pure: indices refer to the arrays as given; the caller maps them to file and line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: s; a gap between two accelerometer samples longer than this is a dropout: no steps are looked for across
#: it and the heading is held. Phones batch samples by up to ~0.35 s (measured on the IPIN 2023 logfiles),
#: so this leaves a margin.
DROPOUT_S = 0.5
#: a block of samples cut off from the rest by a gap longer than ``max_gap_s`` is a stray (bad timestamps,
#: dropped with a warning) when it holds at most this many samples or this fraction of the stream
STRAY_MAX_SAMPLES = 50
STRAY_MAX_FRACTION = 0.01
#: Hz; the uniform grid runs at the accelerometer's median rate, clipped to this range (below 20 Hz a
#: 2 Hz gait is barely sampled; above 200 Hz nothing in a gait needs the detail)
GRID_HZ_MIN, GRID_HZ_MAX = 20.0, 200.0
#: grid points allowed per input sample (plus a constant): more means the timestamps are too irregular
GRID_POINTS_PER_SAMPLE = 4
#: gaps reported one by one up to this many; the rest are counted
MAX_LISTED = 5


@dataclass(frozen=True)
class TimeIssue:
    """A timestamp problem that was repaired (dropped samples, a dropout): ``stream`` is "acc", "gyro" or
    "yaw", ``index`` the sample's position in that stream as given."""

    stream: str
    index: int
    message: str


class ImuTimeError(ValueError):
    """Timestamps that cannot be repaired (a clock jump between two long blocks, hopelessly irregular
    sampling). ``stream`` and ``index`` locate the first bad sample."""

    def __init__(self, stream: str, index: int, message: str) -> None:
        super().__init__(message)
        self.stream = stream
        self.index = index


def main_block(t_s: np.ndarray, max_gap_s: float, stream: str = "acc") -> tuple[np.ndarray, list[TimeIssue]]:
    """Boolean mask (n,) of the samples to keep from time-sorted ``t_s``, and the issues found.

    The stream is cut at every gap longer than ``max_gap_s``. Small blocks (stray timestamps) are dropped;
    two or more large blocks raise :class:`ImuTimeError` at the first sample after the jump.
    """
    t = np.asarray(t_s, dtype=np.float64)
    n = len(t)
    keep = np.ones(n, dtype=bool)
    if n < 2:
        return keep, []
    cut = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    if len(cut) == 0:
        return keep, []
    starts, ends = np.r_[0, cut], np.r_[cut, n]
    sizes = ends - starts
    stray = (sizes <= STRAY_MAX_SAMPLES) | (sizes <= STRAY_MAX_FRACTION * n)
    if (~stray).sum() > 1:
        big = np.flatnonzero(~stray)
        i = int(starts[big[1]])
        raise ImuTimeError(stream, i, f"{stream} time jumps by {t[i] - t[i - 1]:.6g} s (from {t[i - 1]:.6g} to "
                                      f"{t[i]:.6g}): a clock jump or two recordings in one walk; split the file")
    if stray.all():   # only small blocks: keep the largest
        stray[int(np.argmax(sizes))] = False
    issues = []
    for b in np.flatnonzero(stray):
        keep[starts[b]:ends[b]] = False
        issues.append(TimeIssue(stream, int(starts[b]), f"{stream}: {int(sizes[b])} sample(s) at t = "
                                f"{t[starts[b]]:.6g} s, more than {max_gap_s:g} s from the rest, dropped "
                                "(bad timestamp)"))
    return keep, issues


def within(t_s: np.ndarray, lo: float, hi: float, stream: str, margin_s: float) -> tuple[np.ndarray,
                                                                                       list[TimeIssue]]:
    """Mask of the samples of another stream inside the accelerometer's span [lo, hi] ± ``margin_s``;
    samples outside are strays (one issue naming the first of them)."""
    t = np.asarray(t_s, dtype=np.float64)
    keep = (t >= lo - margin_s) & (t <= hi + margin_s)
    if keep.all():
        return keep, []
    i = int(np.argmax(~keep))
    return keep, [TimeIssue(stream, i, f"{stream}: {int((~keep).sum())} sample(s) outside the accelerometer's "
                                       f"time span [{lo:.6g}, {hi:.6g}] s dropped (bad timestamps), first at "
                                       f"t = {t[i]:.6g} s")]


def dropouts(t_s: np.ndarray, stream: str = "acc") -> list[TimeIssue]:
    """One issue per gap longer than :data:`DROPOUT_S` (the first :data:`MAX_LISTED`, then a count)."""
    t = np.asarray(t_s, dtype=np.float64)
    gaps = np.flatnonzero(np.diff(t) > DROPOUT_S) + 1
    out = [TimeIssue(stream, int(i), f"{stream}: no samples for {t[i] - t[i - 1]:.3g} s before t = {t[i]:.6g} s "
                                     "(dropout: no steps there, heading held)") for i in gaps[:MAX_LISTED]]
    if len(gaps) > MAX_LISTED:
        out.append(TimeIssue(stream, int(gaps[MAX_LISTED]), f"{stream}: {len(gaps) - MAX_LISTED} more dropouts"))
    return out


@dataclass(frozen=True)
class Grid:
    """A uniform time grid over the runs of a stream: ``t_s`` (m,) grid times, ``run`` (m,) run index of each
    point, ``fs_hz`` the grid rate. Runs are separated by dropouts; grid points never span one."""

    t_s: np.ndarray
    run: np.ndarray
    fs_hz: float

    def runs(self) -> list[slice]:
        """Slices of the grid arrays, one per run."""
        if len(self.run) == 0:
            return []
        b = np.flatnonzero(np.diff(self.run)) + 1
        return [slice(int(s), int(e)) for s, e in zip(np.r_[0, b], np.r_[b, len(self.run)])]


def uniform_grid(t_s: np.ndarray, stream: str = "acc") -> Grid:
    """The uniform grid for time-sorted samples ``t_s`` (strays already removed).

    The rate is the median sampling rate clipped to [:data:`GRID_HZ_MIN`, :data:`GRID_HZ_MAX`]. Raises
    :class:`ImuTimeError` when the grid would need more than :data:`GRID_POINTS_PER_SAMPLE` points per sample.
    """
    t = np.asarray(t_s, dtype=np.float64)
    if len(t) < 2:
        return Grid(t.copy(), np.zeros(len(t), dtype=np.int64), GRID_HZ_MIN)
    dt = np.diff(t)
    pos = dt[dt > 0]
    med = float(np.median(pos)) if len(pos) else 1.0 / GRID_HZ_MIN
    fs = float(np.clip(1.0 / med, GRID_HZ_MIN, GRID_HZ_MAX))
    cut = np.flatnonzero(dt > DROPOUT_S) + 1
    starts, ends = np.r_[0, cut], np.r_[cut, len(t)] - 1
    counts = np.floor((t[ends] - t[starts]) * fs).astype(np.int64) + 1
    total = int(counts.sum())
    if total > GRID_POINTS_PER_SAMPLE * len(t) + 1000:
        i = int(np.argmax(dt)) + 1
        raise ImuTimeError(stream, i, f"{stream}: timestamps too irregular to resample ({len(t)} samples would "
                                      f"need {total} grid points at {fs:.3g} Hz; longest gap {dt.max():.3g} s)")
    run = np.repeat(np.arange(len(counts)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    tu = t[starts][run] + (np.arange(total) - first) / fs
    return Grid(tu, run, fs)


def resample(grid: Grid, t_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` (n,) or (n, k) sampled at sorted ``t_s``, linearly interpolated onto ``grid``."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        return np.interp(grid.t_s, t_s, v)
    return np.column_stack([np.interp(grid.t_s, t_s, v[:, j]) for j in range(v.shape[1])])
