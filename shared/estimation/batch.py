"""The felt symbol ``g`` of the self's regressors (eq. 3.8, f1-f4 of eq. 3.13-3.16) and its
gradient in the body's parameters ``theta``: of one motion (:func:`g_and_gradient`, the
reference) and of many motions at once (:class:`Batch`, what the body estimate's fit and its
probe choice use). :mod:`shared.estimation.body` says what ``theta`` is."""

from __future__ import annotations

import numpy as np
from scipy import sparse

from shared.errors import BadInput


def regressor_torques(y: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``Y theta`` of a regressor (T, J, P) as one matrix-vector product (4x faster than ``y @ theta``)."""
    y = np.asarray(y, float)
    return (y.reshape(-1, y.shape[-1]) @ theta).reshape(y.shape[:-1])


def g_and_gradient(y: np.ndarray, theta: np.ndarray, rule: str = "eq3.8", tau_max: float = 1.0,
                   weights=None) -> tuple[float, np.ndarray]:
    """``g = F_conv(Y theta)`` (eq. 3.8, 3.13-3.16) and its gradient in ``theta`` (exact where
    no torque changes sign and no maximum changes place; ``g = gradient . theta`` there)."""
    tau = regressor_torques(y, theta)
    w = np.ones(tau.shape[1]) if weights is None else np.asarray(weights, float)
    s = np.sign(tau) * w / tau_max  # d|tau_tj| w_j / tau_max
    a = np.abs(tau) * w / tau_max
    if rule in ("eq3.8", "f1"):
        g = a.sum(axis=1).mean() if rule == "eq3.8" else a.mean()
        grad = np.einsum("tj,tjp->p", s, y) / (len(tau) if rule == "eq3.8" else tau.size)
    elif rule == "f2":
        t = a.argmax(axis=0)
        j = np.arange(tau.shape[1])
        g = a[t, j].sum()
        grad = np.einsum("j,jp->p", s[t, j], y[t, j])
    elif rule == "f3":
        t = int(a.sum(axis=1).argmax())
        g = a[t].sum()
        grad = s[t] @ y[t]
    elif rule == "f4":
        tf, jf = np.unravel_index(int(a.argmax()), a.shape)
        g = a[tf, jf]
        grad = s[tf, jf] * y[tf, jf]
    else:
        raise BadInput(f"unknown conversion rule {rule!r}")
    return float(g), grad


class Batch:
    """Many motions' regressors stacked along time, so that ``g`` of all of them and their
    gradients come from one product (eq. 3.8 and f1), or from one argmax over all their
    frames (f2-f4: :meth:`_peaks`)."""

    def __init__(self, ys: list[np.ndarray], language):
        self.ys = [np.asarray(y, float) for y in ys]
        self.language = language
        self.y = np.concatenate(self.ys, axis=0)
        self.lengths = np.array([len(y) for y in self.ys])
        self.starts = np.r_[0, np.cumsum(self.lengths)[:-1]]
        w = np.ones(self.y.shape[1]) if language.weights is None else np.asarray(language.weights, float)
        self.w = w / language.tau_max
        j = self.y.shape[1]  # each motion's rows in the (frames x joints) flattened regressor
        self.spans = [(int(start) * j, int(start + n) * j) for start, n in zip(self.starts, self.lengths)]
        self._w_tiled: np.ndarray | None = None
        self._pad: tuple[np.ndarray, np.ndarray] | None = None
        self._rows: tuple[np.ndarray, np.ndarray] | None = None  # the sparse sum's column indices and row pointers

    def g(self, theta: np.ndarray) -> np.ndarray:
        """``g`` of every motion (:meth:`g_and_gradient` without the gradient)."""
        if self.language.rule not in ("eq3.8", "f1"):
            return self.g_and_gradient(theta)[0]
        return self._g_of(regressor_torques(self.y, theta))

    def g_and_gradient(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lang = self.language
        if lang.rule not in ("eq3.8", "f1"):
            return self._peaks(theta)
        tau = regressor_torques(self.y, theta)  # (sum T, J)
        s = np.sign(tau.reshape(-1))
        s *= self._w_flat()
        flat = self.y.reshape(len(s), -1)
        # each motion's gradient is the signed sum of its (T J) rows of the regressor: one sparse
        # (motions x rows) product for all of them, 3x faster than a BLAS product per motion on a
        # probe choice's 336 candidates (their Python loop was most of the time)
        if self._rows is None:
            self._rows = np.arange(len(s)), np.r_[[lo for lo, _ in self.spans], len(s)]
        signs = sparse.csr_array((s, *self._rows), shape=(len(self.spans), len(s)), copy=False)
        return self._g_of(tau), (signs @ flat) / self._norm()[:, None]

    def _peaks(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f2-f4 (eq. 3.14-3.16) of every motion at once: the motions' frames side by side,
        padded (a padded frame's |tau| is -1, never a peak), each peak found by one argmax.
        The same numbers as :func:`g_and_gradient` motion by motion, to the bit (tested), 2-3x faster."""
        rule, n_j = self.language.rule, self.y.shape[1]
        if self._pad is None:
            steps = np.arange(int(self.lengths.max()))
            valid = steps[None, :] < self.lengths[:, None]  # (M, T max)
            self._pad = np.where(valid, self.starts[:, None] + steps[None, :], 0), valid
        rows, valid = self._pad
        # one product per motion: BLAS rounds a row by where it falls in the product
        tau = np.concatenate([regressor_torques(y, theta) for y in self.ys])
        w = np.ones(n_j) if self.language.weights is None else np.asarray(self.language.weights, float)
        s = np.sign(tau) * w / self.language.tau_max  # as g_and_gradient computes them
        a = np.abs(tau) * w / self.language.tau_max
        a_pad = np.where(valid[..., None], a[rows], -1.0)  # (M, T max, J)
        if rule == "f2":  # each joint's peak frame
            t = self.starts[:, None] + a_pad.argmax(axis=1)  # (M, J) rows of the stacked frames
            j = np.arange(n_j)[None, :]
            return a[t, j].sum(axis=1), np.einsum("mj,mjp->mp", s[t, j], self.y[t, j])
        if rule == "f3":  # the frame of the largest summed torque
            total = np.where(valid, a_pad.sum(axis=2), -1.0)
            t = self.starts + total.argmax(axis=1)
            return a[t].sum(axis=1), (s[t][:, None, :] @ self.y[t])[:, 0]
        if rule == "f4":  # the one largest torque
            flat = a_pad.reshape(len(self.lengths), -1).argmax(axis=1)
            t, j = self.starts + flat // n_j, flat % n_j
            return a[t, j], s[t, j][:, None] * self.y[t, j]
        raise BadInput(f"unknown conversion rule {rule!r}")

    def _w_flat(self) -> np.ndarray:
        """The joints' weights along the flattened (sum T x J) torques: the products stay
        one-dimensional (broadcasting over a 3-4 wide last axis was most of their time)."""
        if self._w_tiled is None:
            self._w_tiled = np.tile(self.w, len(self.y))
        return self._w_tiled

    def _g_of(self, tau: np.ndarray) -> np.ndarray:
        """eq. 3.8 (or f1) of every motion from the stacked torques (sum T, J)."""
        a = np.abs(tau.reshape(-1))
        a *= self._w_flat()
        a = a.reshape(tau.shape)
        if a.shape[1] < 8:  # each frame's sum column by column: numpy sums fewer than 8 terms in this order too
            row = a[:, 0].copy()
            for j in range(1, a.shape[1]):
                row += a[:, j]
        else:
            row = a.sum(axis=1)
        return np.add.reduceat(row, self.starts) / self._norm()

    def _norm(self) -> np.ndarray:
        return self.lengths * (1 if self.language.rule == "eq3.8" else self.y.shape[1])
