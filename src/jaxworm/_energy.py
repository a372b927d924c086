"""The work-energy balance: W_act = ΔT + ΔV + D + W_bp.

From eq. (17): d(T + V)/dt = Σ F_f,k v_k − F_p v_1 + ∂V/∂l̄·u, so the actuation work
∫∂V/∂l̄·u equals the change of kinetic (eq. 1) and stretching (eq. 2) energy, plus the
friction dissipation D = −∫Σ F_f,k v_k, plus the work against back pressure
W_bp = ∫F_p v_1. Crack jumps move x_c only and leave the balance intact. A solve whose
residual is large relative to the energy that flowed has not solved this ODE.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from . import _physics as phys
from ._dynamics import WormState
from ._params import Params

__all__ = ["energy_terms", "energy_residual"]

#: Energy scale [J] below which a residual is measured absolutely (~1e-10 of a run's work).
ENERGY_FLOOR = 1e-15


def energy_terms(y0: WormState, y: WormState, p: Params) -> dict[str, Float[Array, "*batch"]]:
    """The terms of the balance between two states of one run [J]."""
    b = p.body
    m = b.node_masses
    return {
        "actuation": y.work[..., 0] - y0.work[..., 0],
        "kinetic_change": phys.kinetic_energy(y.v, m) - phys.kinetic_energy(y0.v, m),
        "stretching_change": phys.stretching_energy(y.x, y.lbar, b.EA)
        - phys.stretching_energy(y0.x, y0.lbar, b.EA),
        "friction_dissipation": y.work[..., 1] - y0.work[..., 1],
        "back_pressure_work": y.work[..., 2] - y0.work[..., 2],
    }


def energy_residual(y0: WormState, y: WormState, p: Params) -> Float[Array, "*batch"]:
    """(W_act − ΔT − ΔV − D − W_bp) / (the energy that flowed, at least 1e-15 J):
    relative residual.

    The scale is the largest of |ΔT|, |ΔV|, |D|, |W_bp| and the gross actuation work
    ∫|∂V/∂l̄·u| (≥ |W_act|). In a travelling wave that is the actuation work or the
    dissipation, the gross work somewhat above the net (more over the start's
    transient). In a
    standing wave (δ ≈ 0) the net actuation work is a small difference of large flows
    in and out, ~1e-4 of the gross, so the solver's quadrature error of those flows
    would dominate a residual relative to the net terms alone. In a run the back
    pressure drives (A = 0: the crack pushes the head back, and its work turns into
    kinetic energy and dissipation) the scale is its work. The floor keeps a run in
    which nothing moves from dividing round-off by zero.
    """
    e = energy_terms(y0, y, p)
    res = (
        e["actuation"]
        - e["kinetic_change"]
        - e["stretching_change"]
        - e["friction_dissipation"]
        - e["back_pressure_work"]
    )
    scale = jnp.maximum(ENERGY_FLOOR, jnp.abs(y.work[..., 3] - y0.work[..., 3]))
    for term in e.values():
        scale = jnp.maximum(scale, jnp.abs(term))
    return res / scale
