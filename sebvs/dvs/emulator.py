"""The DVS pixel model of v2e, in our own vectorised code, with v2e's timing defects fixed;
where its noise departs from v2e's, docs/dvs.md's table says so and by how much.

Per pixel, for 8-bit luma x (DN):
    L   = lin-log(x): x * ln(20)/20 for x <= 20, ln(x) above (no log of zero)
    lp  += eps * (L - lp), eps = 1 - exp(-a * dt / tau), a = (x + 20) / 275,
          tau = 1 / (2 pi cutoff_hz): the exact solution of the first-order low-pass for a
          step held over dt, stable for any dt (v2e's Euler eps = min(a dt / tau, 1) is not
          exact and saturates); cutoff_hz = 0 disables the filter (lp = L)
    base, the memorised level: every crossing of base + k * theta (k = 1..n) is an event,
          and base moves by the emitted multiples; the remainder carries over
    leak: base drifts down by dt * leak_rate * theta_on (per-pixel rate), giving ON events;
          from preset_version 2 each pixel starts at a random phase of it (a running
          pixel's memorised level sits anywhere within a threshold below the light), so
          the rate holds from the first frame; version 1 starts every pixel at zero phase,
          and none fires before 1 / leak_rate_hz
    shot noise: events at rate shot_noise_rate_hz times 1 - 0.75 min(x / 255, 1), per
          pixel spread log-normally by noise_rate_cov_decades; from preset_version 2 the
          rates are scaled by the spread's median over its mean, so the stated rate is the
          array's mean (version 1: its median; the mean 1.94x it at 0.5 decades); at most
          one event per pixel and frame
    refractory: events of a pixel closer than refractory_period_s to its previous one are
          dropped (the memorised level still follows the crossings)
    gaps: frames further apart than max_gap_s, forward or back, restart the sensor (state
          from the new frame, no events for the gap; a jump back is a new stream, e.g.
          after one corrupt far-future timestamp), so leak and shot noise never run over an unobserved
          stretch: per pixel and call at most leak_rate * max_gap_s leak events, one shot
          noise event, and the lin-log range over the threshold of crossings

Linear light (step_luminance): a frame of scene luminance in cd/m^2, float, with no upper
bound, is mapped to DN-equivalents x = 255 * L / reference_cd_m2 and runs through the same
model unclipped: the log range is the chip's, not 8 bits', and the photoreceptor's
bandwidth a = (x + 20) / 275 follows the light as in v2e, so a dusk scene (x of a few DN)
has a slow pixel and a sunlit one a fast one. The shot-noise rate falls with the light
(full at x = 0, a quarter at x = 255) and stays at a quarter above: not v2e's, whose line
1 - 0.75 (x + 20) / 275, written for 8-bit input, reaches zero at x = 347 and gives no shot
noise above (1.73 cd/m^2 on the physical preset). reference_cd_m2 is the luminance the
chip's 8-bit-era parameters were set for: the paper's cutoff_hz holds at x = 255.

Timing: the k-th crossing of a pixel is placed where the straight line from the previous
filtered level to the new one crosses base + k * theta (ESIM's interpolation), not in a
slot shared by every pixel's k-th event (v2e's bursts and "pillars"). Timestamps are int64
nanoseconds (v2e's float32 seconds lose microseconds after tens of seconds), and the first
frame's time is remembered (v2e starts from 0, so its second frame sees a huge dt).
Timestamps must lie in [0, 2**63 - 1]; every event time lies between its two frames', so
none wraps.

Work per frame is a few whole-image numpy passes plus work proportional to the number of
events; there is no Python loop over events or over per-frame event slots.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .params import EmulatorParams, lognormal_mean

EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])
THRESHOLD_FLOOR = 0.01
LINLOG_BREAK = 20.0
_DN = np.arange(256, dtype=np.float64)
# lin-log of every 8-bit value, and the intensity factor of the photoreceptor bandwidth
LINLOG = np.where(_DN <= LINLOG_BREAK, _DN * math.log(LINLOG_BREAK) / LINLOG_BREAK,
                  np.log(np.maximum(_DN, LINLOG_BREAK))).astype(np.float32)
BANDWIDTH = ((_DN + 20.0) / 275.0).astype(np.float64)
T_MAX = np.iinfo(np.int64).max
_OFFSET_CAP = float(2 ** 63 - 1024)   # the largest float64 below 2**63


def _lookup(luma: np.ndarray, table: np.ndarray) -> np.ndarray:
    """table[luma] for uint8 luma; OpenCV's LUT is about 3x faster than numpy indexing."""
    return cv2.LUT(np.ascontiguousarray(luma), table.reshape(1, 256))


def linlog(luma: np.ndarray) -> np.ndarray:
    """Lin-log of 8-bit luma: a table lookup for uint8, the formula for float DN."""
    if luma.dtype == np.uint8:
        return _lookup(luma, LINLOG)
    x = luma.astype(np.float64)   # as the table was built: the same value for the same DN
    return np.where(x <= LINLOG_BREAK, x * (math.log(LINLOG_BREAK) / LINLOG_BREAK),
                    np.log(np.maximum(x, LINLOG_BREAK))).astype(np.float32)


def linlog_linear(x: np.ndarray) -> np.ndarray:
    """Lin-log of linear light (float32 DN-equivalents, unbounded), in float32: the same
    curve as linlog() at about a third of its cost, for the path that has no 8-bit table
    to agree with."""
    out = np.maximum(x, np.float32(LINLOG_BREAK))
    cv2.log(out, out)
    low = x < LINLOG_BREAK
    out[low] = x[low] * np.float32(math.log(LINLOG_BREAK) / LINLOG_BREAK)
    return out


def empty_events(n: int = 0) -> np.ndarray:
    return np.zeros(n, EVENT_DTYPE)


_KEY_LIMIT = 2 ** 62   # packed sort keys stay below this, far from int64's edge


def time_order(t: np.ndarray) -> np.ndarray:
    """The permutation ``np.argsort(t, kind="stable")`` gives, for int64 times.

    Packs (t - min, index) into one unique int64 key and sorts it unstably: equal keys
    cannot occur, so the result is the stable order, in a sixth of the time (numpy's
    stable sort of int64 is a merge sort). Falls back to the stable sort where the key
    would not fit.
    """
    n = t.size
    if n < 2:
        return np.arange(n)
    lo = int(t.min())
    if (int(t.max()) - lo + 1) * n >= _KEY_LIMIT:
        return np.argsort(t, kind="stable")
    key = (t - lo) * n
    key += np.arange(n)
    key.sort()
    return key % n


def pixel_time_order(pixel: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The permutation ``np.lexsort((t, pixel))`` gives (by pixel, then time, ties in
    input order), for non-negative int64 pixel indices and times.

    One packed key pixel * span + (t - min) sorted stably: the events arrive nearly in
    pixel order, which the merge sort exploits, where lexsort pays for two full passes.
    """
    n = t.size
    if n < 2:
        return np.arange(n)
    lo = int(t.min())
    span = int(t.max()) - lo + 1
    if (int(pixel.max()) + 1) * span >= _KEY_LIMIT:
        return np.lexsort((t, pixel))
    key = pixel * span
    key += t - lo
    return np.argsort(key, kind="stable")


def _offsets(x: np.ndarray, hi: int) -> np.ndarray:
    """Non-negative float ns offsets -> int64 (truncated), at most ``hi``.

    A float within 1024 ns of 2**63 cannot be cast to int64 (float(2**63 - 1) is 2**63),
    so such offsets, which can only mean "at the end of the interval", become ``hi``.
    Below 2**53 ns (104 days) neither cap binds: the plain cast, bit for bit.
    """
    safe = x < _OFFSET_CAP
    return np.where(safe, np.minimum(np.where(safe, x, 0.0).astype(np.int64), hi), hi)


class EventEmulator:
    """Frames in (uint8 RGB or luma, int ns timestamps), events out (EVENT_DTYPE, sorted by t).

    The first frame initialises the state and emits nothing. A bad frame raises ValueError
    and leaves the state as it was. A frame more than ``max_gap_s`` after (or before) the
    previous one restarts the sensor: nothing is emitted for the gap, and ``gap_restarts``
    counts it; a smaller step back in time is refused.
    """

    def __init__(self, params: EmulatorParams | None = None):
        self.params = (params or EmulatorParams()).validate()
        self.rng = np.random.default_rng(self.params.seed)
        self.shape: tuple[int, int] | None = None   # emulated (H, W)
        self.input_shape: tuple | None = None
        self.t_ns: int | None = None
        self.frames = 0
        self.gap_restarts = 0
        # no int64 dt exceeds 2**63 ns; the cap keeps a max_gap_s of 1e300 (inf ns) legal
        self._max_gap_ns = round(min(self.params.max_gap_s * 1e9, 2.0 ** 63))
        self._eps_key: float | None = None   # dt / tau of the cached low-pass gain table
        self._eps: np.ndarray | None = None
        self._ramp_key: float | None = None  # the same for lowpass_hold "linear"
        self._ramp: tuple[np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ input
    def preprocess(self, frame: np.ndarray) -> np.ndarray:
        """uint8 [H, W] or [H, W, 3] -> uint8 luma at the emulated size."""
        p = self.params
        if frame.ndim == 3:
            frame = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
        if p.downsample != 1.0:
            h, w = frame.shape
            size = (max(1, round(w * p.downsample)), max(1, round(h * p.downsample)))
            frame = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
        if p.blur:
            frame = cv2.GaussianBlur(frame, (3, 3), 0)
        return frame

    def _check(self, frame, t_ns, linear: bool = False) -> tuple[np.ndarray, int]:
        if not isinstance(frame, np.ndarray):
            raise ValueError(f"frame must be a numpy array, got {type(frame).__name__}")
        if frame.dtype != np.uint8:
            if frame.dtype.kind != "f":
                raise ValueError(f"frame dtype {frame.dtype} is not uint8 (or float in DN)")
            if not np.isfinite(frame).all():
                raise ValueError("frame contains NaN or inf")
            if frame.size and frame.min() < 0:
                raise ValueError("frame values must not be negative")
            if not linear and frame.size and frame.max() > 255:
                raise ValueError("float frame values must lie in [0, 255] (8-bit DN); "
                                 "linear luminance goes to step_luminance()")
            frame = frame.astype(np.float32)
        if not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)):
            raise ValueError(f"frame shape {frame.shape} is not (H, W) or (H, W, 3)")
        if frame.shape[0] == 0 or frame.shape[1] == 0:
            raise ValueError(f"frame shape {frame.shape} is empty")
        if self.input_shape is not None and frame.shape != self.input_shape:
            raise ValueError(f"frame shape {frame.shape} differs from the first frame's "
                             f"{self.input_shape}; call reset() for a new stream")
        if isinstance(t_ns, bool) or not isinstance(t_ns, (int, np.integer)):
            raise ValueError(f"timestamp must be an integer number of nanoseconds, got {t_ns!r}")
        t_ns = int(t_ns)
        if not 0 <= t_ns <= T_MAX:
            raise ValueError(f"timestamp {t_ns} ns is outside [0, 2**63 - 1] "
                             "(int64 nanoseconds)")
        # a jump back by more than max_gap_s is a new stream (the previous timestamp was
        # corrupt, or the source restarted) and restarts the sensor; a small step back is
        # out of order and refused
        if self.t_ns is not None and 0 <= self.t_ns - t_ns - 1 < self._max_gap_ns:
            raise ValueError(f"timestamp {t_ns} ns goes back in time (previous {self.t_ns} ns)")
        return np.ascontiguousarray(frame), t_ns

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the stream (a new scene or episode); thresholds are drawn again."""
        self.shape = self.input_shape = self.t_ns = None
        self.frames = self.gap_restarts = 0

    def _init_state(self, luma: np.ndarray, t_ns: int, log=linlog) -> None:
        p = self.params
        h, w = luma.shape
        self.shape = (h, w)
        rng = self.rng
        self.theta_on = np.maximum(rng.normal(p.pos_thres, p.sigma_thres, (h, w)),
                                   THRESHOLD_FLOOR).astype(np.float32)
        self.theta_off = np.maximum(rng.normal(p.neg_thres, p.sigma_thres, (h, w)),
                                    THRESHOLD_FLOOR).astype(np.float32)
        jitter = 1 + p.leak_jitter_fraction * rng.standard_normal((h, w))
        self.leak = (p.leak_rate_hz * np.maximum(jitter, 0)).astype(np.float32) \
            * self.theta_on
        spread = 10.0 ** (p.noise_rate_cov_decades * rng.standard_normal((h, w)))
        rate = p.shot_noise_rate_hz
        if p.preset_version >= 2:
            # the log-normal's median is 1 and its mean exp((c ln 10)^2 / 2): scaled, the
            # stated rate is the array's mean, as its name says (1.94x more at 0.5 decades)
            rate /= lognormal_mean(p.noise_rate_cov_decades)
        self.noise_rate = (rate * spread).astype(np.float32)
        self._start(luma, t_ns, log)

    def _start(self, luma: np.ndarray, t_ns: int, log=linlog) -> None:
        """The pixels' memory (filtered and memorised levels, refractory) from this frame;
        the fixed pattern (thresholds, leak and noise rates) is the chip's and stays."""
        self.lp = log(luma)
        self.l_in = self.lp          # the unfiltered level of the last frame (linear hold)
        self.base = self.lp.copy()
        if self.params.preset_version >= 2 and self.params.leak_rate_hz > 0:
            # a pixel that has been running sits at any phase of its leak; all at zero
            # phase, none would fire before 1 / leak_rate_hz (20 s on the physical preset,
            # ten arm episodes) and then all together
            self.base -= self.rng.random(self.shape, dtype=np.float32) * self.theta_on
        self.last_t = np.full(self.shape, np.iinfo(np.int64).min // 2, np.int64)
        self.t_ns = t_ns

    # ------------------------------------------------------------------ the model
    def step(self, frame: np.ndarray, t_ns: int) -> np.ndarray:
        """Feed one frame taken at ``t_ns``; returns the events since the previous frame."""
        frame, t_ns = self._check(frame, t_ns)
        return self._step(frame, t_ns, linlog)

    def step_luminance(self, luminance: np.ndarray, t_ns: int) -> np.ndarray:
        """Feed one frame of linear scene luminance (cd/m^2, float (H, W) or linear RGB
        (H, W, 3)) taken at ``t_ns``; the events since the previous frame."""
        if isinstance(luminance, np.ndarray) and luminance.dtype.kind != "f":
            raise ValueError(f"luminance dtype {luminance.dtype} is not float (cd/m^2)")
        frame, t_ns = self._check(luminance, t_ns, linear=True)
        scale = np.float32(255.0 / self.params.reference_cd_m2)
        return self._step(frame * scale, t_ns, linlog_linear)

    def _step(self, frame: np.ndarray, t_ns: int, log) -> np.ndarray:
        luma = self.preprocess(frame)
        if self.t_ns is None:
            self.input_shape = frame.shape
            self._init_state(luma, t_ns, log)
            self.frames = 1
            return empty_events()
        dt_ns = t_ns - self.t_ns
        self.frames += 1
        if dt_ns == 0:
            return empty_events()   # a repeated sample carries no new information
        if dt_ns > self._max_gap_ns or dt_ns < 0:
            # Nobody observed the sensor over the gap: leak and shot noise integrated over it
            # would be G * rate events per pixel (25 M on 16 x 16 for 1e6 s), all invented,
            # and the brightness cannot be interpolated across it. Treat it as a restart.
            self._start(luma, t_ns, log)
            self.gap_restarts += 1
            return empty_events()
        p = self.params
        dt = dt_ns * 1e-9
        target = log(luma)
        if p.cutoff_hz > 0 and p.lowpass_hold == "linear":
            lp = self._lowpass_linear(luma, target, dt)
        elif p.cutoff_hz > 0:
            tau = 1.0 / (2 * math.pi * p.cutoff_hz)
            eps = self._lowpass_gain(luma, dt / tau)
            lp = np.subtract(target, self.lp, out=target)   # reuse: target is not needed after
            lp *= eps
            lp += self.lp
        else:
            lp = target
        base = self.base
        if p.leak_rate_hz > 0:
            base = base - np.float32(dt) * self.leak
        events, base = self._crossings(self.lp, lp, base, self.t_ns, dt_ns)
        if p.shot_noise_rate_hz > 0:
            events = np.concatenate([events, self._shot_noise(luma, self.t_ns, dt_ns)])
        if p.refractory_period_s > 0 and events.size:
            events = self._refractory(events)
        events = events[time_order(events["t"])]
        self.lp, self.base, self.t_ns = lp, base, t_ns
        if p.lowpass_hold == "linear":
            self.l_in = target       # not reused in place on this path
        return events

    def _lowpass_linear(self, luma: np.ndarray, target: np.ndarray, dt: float) -> np.ndarray:
        """The filtered level after dt when the input moves linearly from the previous
        frame's level L0 to this one's L1 (lowpass_hold "linear"): the exact solution of
        lp' = (L(t) - lp) / tau_a for a ramp, with k = dt / tau_a,

            lp1 = L1 + (lp0 - L0) exp(-k) - (L1 - L0) (1 - exp(-k)) / k

        The held step ("step") puts the whole change at the start of the interval, so its
        events come early by up to one interval, more the longer the intervals: fine at a
        fixed rate, a bias that grows where an adaptive sampler spaces frames out."""
        tau = 1.0 / (2 * math.pi * self.params.cutoff_hz)
        if luma.dtype == np.uint8:   # per DN value, as the step's gain
            decay, ramp = (_lookup(luma, table) for table in self._ramp_tables(dt / tau))
        else:
            k = luma + np.float32(20.0)
            k *= np.float32(dt / tau / 275.0)
            decay = np.exp(-k)
            ramp = -np.expm1(-k)
            ramp /= k
        l0 = self.l_in
        lp = self.lp - l0
        lp *= decay
        lp += target
        lp -= (target - l0) * ramp
        return lp

    def _ramp_tables(self, dt_over_tau: float) -> tuple[np.ndarray, np.ndarray]:
        """exp(-k) and (1 - exp(-k)) / k per DN value, k = a dt / tau (kept while dt holds)."""
        if dt_over_tau != self._ramp_key:
            k = BANDWIDTH * dt_over_tau
            self._ramp = (np.exp(-k).astype(np.float32),
                          (-np.expm1(-k) / k).astype(np.float32))
            self._ramp_key = dt_over_tau
        return self._ramp

    def _lowpass_gain(self, luma: np.ndarray, dt_over_tau: float) -> np.ndarray:
        """The step low-pass's gain per pixel over one interval, 1 - exp(-a(x) dt / tau)
        with the bandwidth a(x) = (x + 20) / 275 of the pixel's level x (float32 [H, W])."""
        if luma.dtype == np.uint8:   # one exponential per DN value, not per pixel
            return _lookup(luma, self._eps_table(dt_over_tau))
        # in place, the operations of -expm1(-((x + 20) / 275) * dt / tau)
        eps = luma + np.float32(20.0)
        eps /= np.float32(275.0)
        np.negative(eps, out=eps)
        eps *= np.float32(dt_over_tau)
        np.expm1(eps, out=eps)
        np.negative(eps, out=eps)
        return eps

    def _eps_table(self, dt_over_tau: float) -> np.ndarray:
        """The low-pass gain per DN value for this dt / tau; a camera at a fixed rate sends
        one dt, so the table is kept until that changes."""
        if dt_over_tau != self._eps_key:
            self._eps = (-np.expm1(-BANDWIDTH * dt_over_tau)).astype(np.float32)
            self._eps_key = dt_over_tau
        return self._eps

    def _crossings(self, lp0, lp1, base, t0, dt_ns):
        """Events of the level crossings between two filtered frames; the new base."""
        diff = lp1 - base
        pixels, times, sizes = [], [], []   # per polarity, ON then OFF
        new_base = base
        for pol, theta in ((1, self.theta_on), (-1, self.theta_off)):
            over = diff >= theta if pol > 0 else diff <= -theta
            idx = np.flatnonzero(over)
            if idx.size == 0:
                continue
            d = diff.ravel()[idx] * pol
            th = theta.ravel()[idx]
            n = np.floor(d / th).astype(np.int64)
            n = np.maximum(n, 1)
            if new_base is base:
                new_base = base.copy()
            new_base.ravel()[idx] += pol * n * th
            # k-th crossing of each pixel: level base + pol * k * theta
            rep = np.repeat(np.arange(idx.size), n)
            k = np.arange(rep.size) - np.repeat(np.cumsum(n) - n, n) + 1
            # float64 here: a float32 fraction of a 10 ms interval is off by nanoseconds
            b0 = base.ravel()[idx][rep].astype(np.float64)
            l0 = lp0.ravel()[idx][rep].astype(np.float64)
            l1 = lp1.ravel()[idx][rep].astype(np.float64)
            level = b0 + pol * k * th[rep].astype(np.float64)
            span = l1 - l0
            with np.errstate(divide="ignore", invalid="ignore"):
                frac = np.where(np.abs(span) > 1e-12, (level - l0) / span, 1.0)
            # clip passes NaN through and sends +-inf to 1 and 0, as clipping after
            # nan_to_num did; then NaN -> 1. (nan_to_num costs ~14 us a call, 3x this.)
            np.clip(frac, 0.0, 1.0, out=frac)
            frac[np.isnan(frac)] = 1.0
            # strictly after the previous frame: its own events sit at t0
            t = t0 + np.maximum(1, _offsets(np.rint(frac * dt_ns), dt_ns))
            pixels.append(idx[rep])
            times.append(t)
            sizes.append((pol, rep.size))
        # one structured array filled field by field: concatenating structured arrays
        # costs tens of us a call (field promotion), plain columns next to nothing
        if not pixels:
            return empty_events(), new_base
        pix = np.concatenate(pixels)
        events = np.empty(pix.size, EVENT_DTYPE)
        events["y"], events["x"] = np.divmod(pix, self.shape[1])
        events["t"] = np.concatenate(times)
        start = 0
        for pol, size in sizes:
            events["p"][start:start + size] = pol
            start += size
        return events, new_base

    def _shot_noise(self, luma, t0, dt_ns) -> np.ndarray:
        """At most one noise event per pixel per frame, probability rate * dt (capped at 1)."""
        dt = dt_ns * 1e-9
        brightness = np.minimum(luma.astype(np.float32) / 255.0, 1.0)
        prob = self.noise_rate * (1.0 - 0.75 * brightness) * dt
        hit = np.flatnonzero(self.rng.random(self.shape, dtype=np.float32) < prob)
        ev = np.empty(hit.size, EVENT_DTYPE)
        ev["y"], ev["x"] = np.divmod(hit, self.shape[1])
        ev["t"] = t0 + 1 + _offsets(self.rng.random(hit.size) * (dt_ns - 1), dt_ns - 1)
        ev["p"] = np.where(self.rng.random(hit.size) < 0.5, 1, -1)
        return ev

    def _refractory(self, events: np.ndarray) -> np.ndarray:
        """Drop events of a pixel that come within the refractory period of the one it kept."""
        # beyond 2**62 ns (146 years) the period is infinite for int64 times anyway
        period = int(min(self.params.refractory_period_s * 1e9, 2.0 ** 62))
        w = self.shape[1]
        pix = events["y"].astype(np.int64) * w + events["x"]
        order = pixel_time_order(pix, events["t"])
        pix_s, t_s = pix[order], events["t"][order]
        keep = np.zeros(order.size, bool)
        # per pixel, walk its events in time order, vectorised across pixels by rank;
        # after rank 0 only the (few) pixels with more events stay in the walk
        start = np.r_[0, np.flatnonzero(np.diff(pix_s)) + 1]
        counts = np.diff(np.r_[start, pix_s.size])
        first = pix_s[start]
        last = self.last_t.ravel()[first]
        ok = t_s[start] - period >= last      # last + period could pass 2**63 - 1
        keep[start[ok]] = True
        last[ok] = t_s[start[ok]]
        live = np.flatnonzero(counts > 1)
        pos, left = start[live] + 1, counts[live] - 1
        while live.size:
            ok = t_s[pos] - period >= last[live]
            keep[pos[ok]] = True
            last[live[ok]] = t_s[pos[ok]]
            more = left > 1
            live, pos, left = live[more], pos[more] + 1, left[more] - 1
        self.last_t.ravel()[first] = last
        return events[np.sort(order[keep])]
