r"""Periodic functions of the phase as real Fourier series.

A series of degree M is the coefficient vector :math:`c = (c_0, a_1..a_M, b_1..b_M)` of

.. math::

    f(\phi) = c_0 + \sum_{m=1}^{M} (a_m \cos m\phi + b_m \sin m\phi),

so ``trig(phi, M) @ c`` evaluates it, ``differentiate(c)`` is the series of :math:`df/d\phi`
(spectral differentiation: exact for the series), and by Parseval
:math:`\frac{1}{2\pi}\int_0^{2\pi} f^2 d\phi = c_0^2 + \frac12 \sum_m (a_m^2 + b_m^2)`.
Coefficient matrices (one column per parameter) work the same way.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq
from scipy.special import ive

#: Harmonics whose von Mises coefficient is below this fraction of the mean are dropped.
TAIL = 1e-17
#: The default width keeps the first harmonic's alias (harmonic N - 1) below this fraction of it.
ALIAS = 1e-2
#: The default width is at least this [-]: a basis function falls to 1/e at the opposite phase.
MIN_DEFAULT_WIDTH = 0.5


def degree(coefficients: np.ndarray) -> int:
    """M of a coefficient vector or matrix (rows ``2M + 1``)."""
    return (len(coefficients) - 1) // 2


def trig(phi: np.ndarray | float, M: int) -> np.ndarray:
    """``(n, 2M + 1)`` rows :math:`(1, \\cos\\phi..\\cos M\\phi, \\sin\\phi..\\sin M\\phi)` at
    the phases ``phi`` [rad]."""
    ang = np.multiply.outer(np.atleast_1d(np.asarray(phi, dtype=float)), np.arange(1, M + 1))
    return np.concatenate([np.ones(ang.shape[:-1] + (1,)), np.cos(ang), np.sin(ang)], axis=-1)


def differentiate(c: np.ndarray) -> np.ndarray:
    """The series of the phase derivative (rows as in :func:`trig`)."""
    M = degree(c)
    m = np.arange(1, M + 1).reshape((M,) + (1,) * (c.ndim - 1))
    d = np.zeros_like(c)
    d[1:M + 1] = m * c[M + 1:]
    d[M + 1:] = -m * c[1:M + 1]
    return d


def pad(c: np.ndarray, M: int) -> np.ndarray:
    """The same series written with degree ``M`` (higher harmonics zero, or dropped)."""
    K = degree(c)
    out = np.zeros((2 * M + 1,) + c.shape[1:])
    k = min(K, M)
    out[0] = c[0]
    out[1:k + 1] = c[1:k + 1]
    out[M + 1:M + 1 + k] = c[K + 1:K + 1 + k]
    return out


def parseval_rows(c: np.ndarray) -> np.ndarray:
    """Rows scaled so that the sum of squares is :math:`\\frac{1}{\\pi}\\int_0^{2\\pi} f^2`
    (least squares over the coefficients is then least squares over the phase)."""
    out = np.array(c, dtype=float)
    out[0] = out[0] * np.sqrt(2.0)
    return out


def from_samples(y: np.ndarray, periods: int = 1) -> np.ndarray:
    """The series through equally spaced samples that span ``periods`` whole periods (the sample
    after the last would be the first again): the trigonometric interpolant, by the FFT, of
    every harmonic the samples resolve (below their Nyquist frequency); with several periods,
    what is not periodic with the period averages out."""
    y = np.asarray(y, dtype=float)
    n = len(y)
    Y = np.fft.rfft(y) / n
    M = (n - 1) // (2 * periods)  # m * periods < n / 2
    bins = periods * np.arange(1, M + 1)
    return np.concatenate([[Y[0].real], 2.0 * Y[bins].real, -2.0 * Y[bins].imag])


def von_mises_harmonics(width: float) -> int:
    """Harmonics of the von Mises basis :math:`\\exp(h(\\cos\\phi - 1))` above :data:`TAIL`
    of its mean (its coefficients :math:`2 e^{-h} I_m(h)` fall faster than
    :math:`e^{-m^2/2h}`)."""
    m = np.arange(int(9.5 * np.sqrt(width)) + 60)
    small = ive(m, width) < TAIL * ive(0, width)
    return int(np.argmax(small)) if small.any() else len(m)


def basis_alias(n_basis: int, width: float) -> float:
    """How much harmonic N - 1 comes with the first harmonic [-]: with N equally spaced centres
    the weights that make :math:`\\cos\\phi` from the basis make :math:`\\cos (N-1)\\phi` too,
    with :math:`I_{N-1}(h)/I_1(h)` of its amplitude (the discrete Fourier transform over the
    centres folds harmonic m onto m mod N)."""
    return float(ive(n_basis - 1, width) / ive(1, width))


def default_width(n_basis: int) -> float:
    """The basis width h [-] when none is given: N / 2, or wider where N / 2 aliases.

    N / 2 keeps the q''-ripple of a fit small (docs/theory.md), but with few functions the
    first harmonic drags its alias along: at N = 5 and h = 2.5 harmonic 4 at 5.5 % of it, a
    floor no learning gets below (a sine fitted by the RMP to 5 % RMS). The default is the
    largest h <= N / 2 with :func:`basis_alias` at most :data:`ALIAS`, and at least
    :data:`MIN_DEFAULT_WIDTH` (below it the functions barely differ and their weights grow as
    1/h). N >= 7 keeps N / 2; N <= 2 has no alias to keep down (N / 2)."""
    half = n_basis / 2.0
    if n_basis <= 2 or basis_alias(n_basis, half) <= ALIAS:
        return half
    if basis_alias(n_basis, MIN_DEFAULT_WIDTH) >= ALIAS:
        return MIN_DEFAULT_WIDTH
    return float(brentq(lambda h: basis_alias(n_basis, h) - ALIAS, MIN_DEFAULT_WIDTH, half,
                        xtol=1e-12))


def von_mises(width: float, centers: np.ndarray, M: int) -> np.ndarray:
    """``(2M + 1, N)``: the series of :math:`\\psi_i(\\phi) = \\exp(h(\\cos(\\phi - c_i) - 1))`
    (Jacobi-Anger: :math:`e^{h\\cos x} = I_0(h) + 2\\sum_m I_m(h)\\cos mx`)."""
    m = np.arange(1, M + 1)[:, None]
    amp = 2.0 * ive(m, width)
    return np.concatenate([np.full((1, len(centers)), ive(0, width)),
                           amp * np.cos(m * centers), amp * np.sin(m * centers)])


__all__ = ["basis_alias", "default_width", "degree", "differentiate", "from_samples", "pad",
           "parseval_rows", "trig", "von_mises", "von_mises_harmonics"]
