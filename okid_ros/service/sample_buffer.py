"""Ring buffer of recent samples (stamp, u, y, skipped), indexed by an absolute sample counter.

Node 2 keeps the samples of the ARX window in one (for the realization and the warm start of
each model), node 1 the samples it may have to replay into its window after a structural
change. Thread-safe: the per-sample path appends while a worker reads copies.

``skipped`` is what :meth:`okid_ros.service.estimation.ModalEstimationService.step` receives:
0 for a contiguous sample, ``k > 0`` after ``k`` missing slots, -1 after a restart.
"""

from __future__ import annotations

import math
import os
import threading

import numpy as np

__all__ = ["SampleBuffer", "MEMORY_SHARE", "physical_memory_bytes", "available_memory_bytes", "memory_shortfall"]

#: The largest share of this machine's memory a buffer sized from an ARX window may take.
MEMORY_SHARE = 0.5


def physical_memory_bytes() -> int:
    """Memory of this machine [bytes] (0 when the system does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


def available_memory_bytes() -> int:
    """Memory this process may still take [bytes] (0 when the system does not say).

    The kernel's estimate of what can be had without swapping (``MemAvailable`` of /proc/meminfo,
    else the free pages), and less under an address-space limit (``ulimit -v``): there what the
    process has mapped already counts against the limit.
    """
    available = 0
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            available = next((int(line.split()[1]) * 1024 for line in meminfo if line.startswith("MemAvailable:")), 0)
    except (OSError, ValueError, IndexError):
        pass
    if not available:
        try:
            available = int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_AVPHYS_PAGES"))
        except (ValueError, OSError, AttributeError):
            available = 0
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        if limit != resource.RLIM_INFINITY:
            with open("/proc/self/statm", encoding="ascii") as statm:
                mapped = int(statm.read().split()[0]) * int(os.sysconf("SC_PAGE_SIZE"))
            room = max(limit - mapped, 1)
            available = min(available, room) if available else room
    except (ImportError, OSError, ValueError, IndexError):
        pass
    return available


def memory_shortfall(need_bytes: float) -> str:
    """"needs about X GiB, only Y GiB available" when ``need_bytes`` do not fit, else "".

    The one wording for options sized beyond this machine (``arx.window_length``, ``simulate
    --duration``); "" too when the system does not say what is available.
    """
    available = available_memory_bytes()
    if not available or need_bytes <= available:
        return ""
    return f"needs about {need_bytes / 2**30:.3g} GiB, only {available / 2**30:.3g} GiB available"


class SampleBuffer:
    """Ring buffer of recent samples, indexed by an absolute sample counter; thread-safe."""

    def __init__(self, capacity: int, m: int, p: int) -> None:
        self.lock = threading.Lock()
        self.m, self.p = m, p
        self._alloc(max(int(capacity), 16))
        self.count = 0
        self._oldest = 0  # no sample before this one is held (a resize keeps only what the ring held)
        self._restart = 0  # the newest sample appended after a restart (skipped < 0), or 0
        self._glitches: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # predicted_glitch's, by sample

    def _alloc(self, cap: int) -> None:
        self.cap = cap
        self.stamps = np.zeros(cap)
        self.u = np.zeros((cap, self.m))
        self.y = np.zeros((cap, self.p))
        self.skipped = np.zeros(cap, dtype=np.int64)

    def clear(self) -> None:
        with self.lock:
            self.count = self._oldest = self._restart = 0
            self._glitches = {}

    def resize(self, cap: int) -> None:
        with self.lock:
            if cap <= self.cap:
                return
            first = self.first
            old = [self._ordered(array, first, self.count) for array in (self.stamps, self.u, self.y, self.skipped)]
            self._alloc(cap)
            self._oldest = first  # the samples the smaller ring had let go are not held again
            new = np.arange(first, self.count) % cap
            self.stamps[new], self.u[new], self.y[new], self.skipped[new] = old

    def grow_for(self, need: int, limit: int, limit_name: str) -> str:
        """Grow to hold ``need`` samples with 10 % (and 64) to spare; why it may not, or "".

        At most ``limit`` samples (``limit_name`` says whose limit that is) and at most
        :data:`MEMORY_SHARE` of this machine's memory. The window comes from a message anyone on
        the domain may publish, and numpy's zeroed arrays take memory only as samples fill them:
        an absurd window raised no allocation error, it made a node whose memory grew for days.
        """
        if self.cap >= need * 1.1 + 64:
            return ""
        if need > limit:
            return f"its window of {need} samples (rows + order) is more than the {limit} of {limit_name}"
        cap = min(int(need * 1.1) + 64, limit)
        size, memory = cap * 8 * (2 + self.m + self.p), physical_memory_bytes()
        if memory and size > MEMORY_SHARE * memory:
            return (f"buffering its window of {need} samples takes {size / 2**30:.3g} GiB, more than "
                    f"{MEMORY_SHARE:.0%} of this machine's {memory / 2**30:.3g} GiB")
        self.resize(cap)
        return ""

    def append(self, stamp_s: float, u: np.ndarray, y: np.ndarray, skipped: int) -> int:
        with self.lock:
            i = self.count % self.cap
            self.stamps[i] = stamp_s
            self.u[i] = u
            self.y[i] = y
            self.skipped[i] = skipped
            if skipped < 0:
                self._restart = self.count
            self.count += 1
            return self.count - 1

    def add_to_outputs(self, lo: int, hi: int, delta: np.ndarray) -> None:
        """Add ``delta`` (p,) to the stored outputs of samples lo..hi-1 (clipped to what is stored)."""
        with self.lock:
            idx = np.arange(max(lo, self.first), max(min(hi, self.count), lo)) % self.cap
            self.y[idx] += delta
            for i, (outputs, values) in self._glitches.items():
                if lo <= i < hi:
                    self._glitches[i] = (outputs, values + delta)

    def predicted_glitch(self, index: int, outputs: np.ndarray, values: np.ndarray) -> None:
        """Sample ``index`` a glitch in ``outputs`` (p,) bool, predicted as ``values`` (p,) there.

        Kept beside the sample as it came: :meth:`get` returns either (a realization window's spike
        rule judges the samples as they came, as ``identify`` does; a predictor's state follows the
        prediction, as the estimator in use did).
        """
        with self.lock:
            if self.first <= index < self.count:
                self._glitches = {i: g for i, g in self._glitches.items() if i >= self.first}
                self._glitches[int(index)] = (np.asarray(outputs, bool).copy(), np.asarray(values, float).copy())

    @property
    def first(self) -> int:
        """Absolute index of the oldest sample held."""
        return max(self.count - self.cap, self._oldest)

    def get(self, lo: int, hi: int, *, predicted_glitches: bool = False
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Copies of samples lo..hi-1 (absolute indices, clipped to what is stored).

        ``predicted_glitches``: the glitches' outputs as predicted (:meth:`predicted_glitch`), not as they came.
        """
        with self.lock:
            lo = max(lo, self.first)
            hi = max(min(hi, self.count), lo)
            y = self._ordered(self.y, lo, hi)
            if predicted_glitches:
                for i, (outputs, values) in self._glitches.items():
                    if lo <= i < hi:
                        y[i - lo, outputs] = values[outputs]
            return (self._ordered(self.stamps, lo, hi), self._ordered(self.u, lo, hi), y,
                    self._ordered(self.skipped, lo, hi))

    def _ordered(self, array: np.ndarray, lo: int, hi: int) -> np.ndarray:
        """A copy of ``array``'s rows of samples lo..hi-1 (stored, lo <= hi), oldest first.

        One or two slices of the ring: a fancy index of thousands of rows cost ~10x as much, with
        the lock held that the sample path's :meth:`append` waits for.
        """
        start, end = lo % self.cap, lo % self.cap + (hi - lo)
        if end <= self.cap:
            return array[start:end].copy()
        return np.concatenate([array[start:], array[: end - self.cap]])

    def find_end(self, stamp_s: float, tol: float) -> tuple[int, float]:
        """Newest stored sample with stamp <= stamp_s + tol (index, its stamp), or (-1, nan).

        Searched within the newest contiguous timeline (after the last restart).
        """
        with self.lock:
            lo, hi = self.first, self.count
            if hi == lo:
                return -1, math.nan
            st = self._ordered(self.stamps, lo, hi)
            start = self._timeline_start(lo)
            ok = np.flatnonzero(st[start:] <= stamp_s + tol)
            if ok.size == 0:
                return -1, math.nan
            k = start + int(ok[-1])
            return lo + k, float(st[k])

    def newest_stamp(self) -> float:
        with self.lock:
            return float(self.stamps[(self.count - 1) % self.cap]) if self.count else math.nan

    def stamp_at(self, index: int) -> float:
        """Stamp of the sample with absolute index ``index`` (nan if no longer stored)."""
        with self.lock:
            if not self.first <= index < self.count:
                return math.nan
            return float(self.stamps[index % self.cap])

    def first_at_or_after(self, stamp_s: float, tol: float = 0.0) -> int:
        """Oldest stored sample of the newest timeline with stamp >= ``stamp_s - tol``; -1 if none."""
        with self.lock:
            lo, hi = self.first, self.count
            if hi == lo:
                return -1
            start = self._timeline_start(lo)
            ok = np.flatnonzero(self._ordered(self.stamps, lo, hi)[start:] >= stamp_s - tol)
            return -1 if ok.size == 0 else lo + start + int(ok[0])

    def timeline_start_stamp(self) -> float:
        """Stamp of the oldest stored sample of the newest timeline (after the last restart); nan if none."""
        with self.lock:
            lo, hi = self.first, self.count
            return math.nan if hi == lo else float(self.stamps[(lo + self._timeline_start(lo)) % self.cap])

    def _timeline_start(self, lo: int) -> int:
        """Offset from ``lo`` of the newest timeline's first sample among the samples from ``lo`` on (lock held).

        Kept at each append: a search of the ring took 6 us at 6600 samples, and node 2 looks at every
        sample while a model waits for its window's end (``ModalEstimationService.take_job``).
        """
        return max(self._restart, lo) - lo
