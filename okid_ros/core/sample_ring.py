"""A ring of per-sample rows addressed by sample index, for looking back over the last samples.

The model-error check keeps its residuals and inputs in two, the change monitor and the
divergence watchdog the whitened innovations the state-jump test fits.

No rclpy; numpy only.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SampleRing"]


class SampleRing:
    """The last ``capacity`` rows of a per-sample signal, addressed by sample index (slot = index % capacity).

    Writing a sample again replaces it (a corrected innovation takes the place of the first).

    Parameters
    ----------
    width : values per sample.
    capacity : samples kept.
    """

    def __init__(self, width: int, capacity: int) -> None:
        self.capacity = int(capacity)
        self._z = np.zeros((self.capacity, int(width)))
        self._index = np.full(self.capacity, -1, dtype=np.int64)

    def clear(self) -> None:
        self._index[:] = -1

    def push(self, first_index: int, z: np.ndarray) -> None:
        """Rows ``z`` (N, width) of samples ``first_index ..``."""
        cap = self._z.shape[0]
        z = np.asarray(z, dtype=float)
        if z.shape[0] > cap:  # only the newest fit
            first_index, z = first_index + z.shape[0] - cap, z[-cap:]
        if z.shape[0] == 1:
            self.push_one(int(first_index), z[0])
            return
        index = int(first_index) + np.arange(z.shape[0])
        self._z[index % cap], self._index[index % cap] = z, index

    def push_one(self, index: int, row: np.ndarray) -> None:
        """The row (width,) of sample ``index``: :meth:`push` of one sample, for the per-sample path."""
        slot = index % self.capacity
        self._z[slot], self._index[slot] = row, index

    def since(self, first_index: int, last_index: int) -> tuple[np.ndarray, int]:
        """The held rows of samples ``first_index .. last_index`` that run without a gap to the last.

        Returns ``(z (L, width), index of its first row)``; L is 0 if the last sample is not held.
        """
        cap = self._z.shape[0]
        index = int(last_index) - np.arange(min(int(last_index) - int(first_index) + 1, cap))  # newest first
        index = index[index >= 0]
        held = self._index[index % cap] == index
        run = held.size if held.all() else int(np.argmin(held))
        return self._z[index[:run][::-1] % cap].copy(), int(last_index) - run + 1
