"""Divergence of the state estimator: its whitened innovations far beyond their covariance.

A sample is *diverged* when its innovation is not finite or the mean normalized innovation
squared over the last ``window_samples`` samples exceeds ``nis_ratio * p`` (see
:mod:`okid_ros.core.change_detection`, which re-exports :class:`DivergenceMonitor`).

No rclpy; numpy only.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DivergenceMonitor"]


class DivergenceMonitor:
    """Flags diverged samples and sustained divergence (see the module docstring).

    Parameters
    ----------
    n_outputs : p.
    window_samples : samples of the moving mean of ``nis`` and of divergence before it is
        sustained.
    nis_ratio : the moving mean above ``nis_ratio * p`` is divergence.
    """

    def __init__(self, n_outputs: int, *, window_samples: int = 25, nis_ratio: float = 100.0) -> None:
        if int(window_samples) < 1 or not nis_ratio > 1.0:
            raise ValueError("window_samples must be >= 1 and nis_ratio > 1")
        self.n_outputs = int(n_outputs)
        self.window_samples = int(window_samples)
        self.nis_ratio = float(nis_ratio)
        self.restart()

    def restart(self) -> None:
        self._recent = np.zeros(self.window_samples)
        self._count = 0
        self.consecutive = 0

    def check(self, whitened: np.ndarray) -> bool:
        """One sample's whitened innovation (p,); returns whether the sample is diverged."""
        nis = float(whitened.dot(whitened))  # (ndarray.dot: numpy.dot without its function dispatch)
        if not math.isfinite(nis):
            self.consecutive += 1
            return True
        self._recent[self._count % self.window_samples] = nis
        self._count += 1
        n = min(self._count, self.window_samples)
        diverged = self._recent.sum() / n > self.nis_ratio * self.n_outputs
        self.consecutive = self.consecutive + 1 if diverged else 0
        return diverged

    @property
    def nis_ratio_now(self) -> float:
        """Moving mean of the normalized innovation squared over its expectation p."""
        n = min(self._count, self.window_samples)
        return float(self._recent.sum() / (n * self.n_outputs)) if n else math.nan

    @property
    def sustained(self) -> bool:
        """Diverged for ``window_samples`` samples in a row."""
        return self.consecutive >= self.window_samples
