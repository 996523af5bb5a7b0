r"""Learning rates in physical units: one number means the same step at any sampling.

Eq. 3.6 sums :math:`J_k^\top e_k` over the N samples of a cycle, so its step grows with the
control rate and the period (N = period_s * rate_hz), and with the basis size through the
features. feltool reads ``learning.rates`` as rates of the *mean* over the cycle (the integral
over one revolution of the phase divided by the period) and divides the weight rate by the
basis's gain :math:`\kappa_0` (:func:`basis_gain`):

.. math::

    \Delta w = \frac{\alpha_w}{\kappa_0}\,\frac{1}{N}\sum_{k=1}^{N} \varpi_k J_{w,k}^\top e_k,
    \qquad
    \Delta g = \alpha_g\,\frac{1}{N}\sum_{k=1}^{N} \varpi_k J_{g,k}^\top e_k

(:math:`\varpi_k` the phase step k covers relative to a nominal step, 1 on the nominal
cycle). The engines keep summing; they are handed the per-sample rates
:math:`\alpha_w / (N\kappa_0)` and :math:`\alpha_g / N` (:func:`per_sample_rates`), so both
engines and every cycle kind (per cycle, per step, walkers) get the same scaling from one
place. The Gauss-Newton (Levenberg-Marquardt) step is invariant to all of these already: its
rate ``learning.rates.gauss_newton`` is the fraction of the step taken. The translation of the
shipped configs' old per-sample rates is :func:`translate` (docs/theory.md, next to eq. 3.6).
"""

from __future__ import annotations

import numpy as np

from feltool.motion.spectral import default_width

#: Phase samples of one revolution on which :func:`basis_gain` averages (independent of the
#: control rate: the basis is a function of the phase).
GAIN_SAMPLES = 2048


def samples_per_cycle(period_s: float, rate_hz: float) -> float:
    """N, the control steps of one nominal cycle: ``period_s`` [s] times ``rate_hz`` [Hz]."""
    return float(period_s) * float(rate_hz)


def basis_gain(n_basis: int, width: float, amplitude: float = 1.0) -> float:
    r""":math:`\kappa_0`: the mean over one revolution of the phase of the squared sum of the
    forcing's basis, :math:`\overline{(r\sum_i\psi_i(\phi))^2}` [-] (von Mises
    :math:`\psi_i = e^{h(\cos(\phi - c_i) - 1)}`, centres :math:`c_i = 2\pi i/N_b`). With the
    default width h = N_b/2 it grows about in proportion to the basis size N_b, as the gradient
    step's gain on the trajectory does; dividing the weight rate by it makes the step
    independent of the basis size."""
    phi = np.linspace(0.0, 2.0 * np.pi, GAIN_SAMPLES, endpoint=False)[:, None]
    centers = 2.0 * np.pi * np.arange(int(n_basis)) / int(n_basis)
    psi = np.exp(float(width) * (np.cos(phi - centers) - 1.0))
    return float(np.mean((float(amplitude) * psi.sum(axis=1)) ** 2))


def per_sample_rates(weights: float, goal: float, n_samples: float, kappa: float,
                     gauss_newton: float | None = None) -> tuple[float, float]:
    """The rates the engines' sums use for one joint, ``(weight rate, goal rate)``.

    Args:
        weights: ``learning.rates.weights`` (gradient) [rad / (N m)^2 per cycle, mean].
        goal: ``learning.rates.goal`` [rad / (N m)^2 per cycle, mean].
        n_samples: N, control steps of the nominal cycle (:func:`samples_per_cycle`).
        kappa: The joint's basis gain (:func:`basis_gain`).
        gauss_newton: ``learning.rates.gauss_newton`` when the weights take the
            Levenberg-Marquardt step (a fraction, not scaled), else None.
    """
    w = gauss_newton if gauss_newton is not None else weights / (n_samples * kappa)
    return float(w), float(goal) / n_samples


def translate(per_sample_weights: float, per_sample_goal: float, period_s: float,
              rate_hz: float, n_basis: int, width: float | None = None,
              amplitude: float = 1.0) -> tuple[float, float]:
    """Old per-sample rates (the sums of eq. 3.6 as the thesis wrote them) as the rates of
    this module that give the very same step: ``(weights * N * kappa_0, goal * N)``."""
    n = samples_per_cycle(period_s, rate_hz)
    kappa = basis_gain(n_basis, default_width(n_basis) if width is None else width, amplitude)
    return per_sample_weights * n * kappa, per_sample_goal * n


__all__ = ["GAIN_SAMPLES", "basis_gain", "per_sample_rates", "samples_per_cycle", "translate"]
