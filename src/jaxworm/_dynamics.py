"""The state-space model (eqs. 17-23) as a pure vector field, and the crack condition.

The state is (x, v, l̄) with three running integrals for the energy balance; the crack
tip x_c is constant between crack events and travels in `args`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import lu_factor, lu_solve
from jaxtyping import Array, Float

from . import _physics as phys
from ._params import Params

__all__ = ["WormState", "initial_state", "initial_crack_tip", "vector_field",
           "forces", "vector_field_stiff", "vector_field_nonstiff", "crack_condition", "crack_jump", "stress_intensity_of",
           "newton_factor"]

# Smallest head-to-tip gap the formulas see, relative to l_0. Only a state that has
# overshot the crack event reaches it; K_I is then huge, so the event still fires.
_GAP_FLOOR = 1e-9


class WormState(eqx.Module):
    """State of the ODE.

    - `x`, `v`: node positions [m] and velocities [m/s], head first (N,).
    - `lbar`: intrinsic segment lengths l̄ [m] (N−1,), integrated from u (eq. 23).
    - `work`: running integrals [J]: actuation work ∫∂V/∂l̄·u, friction dissipation
      −∫Σ F_f,k v_k and back-pressure work ∫F_p v_1 (for the energy balance).
    """

    x: Float[Array, " N"]
    v: Float[Array, " N"]
    lbar: Float[Array, " S"]
    work: Float[Array, " 3"]


def initial_state(p: Params) -> WormState:
    """Rest, unstretched, head at 0: x_k(0) = −(k−1) l_0, v = 0 (`MODEL.md`)."""
    b = p.body
    x = -jnp.arange(b.N) * b.l0
    return WormState(x=x, v=jnp.zeros(b.N), lbar=p.gait.lbar0(b) * jnp.ones(b.N - 1),
                     work=jnp.zeros(3))


def initial_crack_tip(p: Params, y0: WormState):
    """x_c(0): eq. (13) at t = 0 (K_I(0) = K_Ith), or x_1(0) + `crack_gap0`."""
    if p.crack_gap0 is not None:
        return y0.x[0] + p.crack_gap0
    return crack_jump(y0, p)


def _gap(x, x_c, p: Params):
    return jnp.maximum(x_c - x[0], _GAP_FLOOR * p.body.l0)


def stress_intensity_of(y: WormState, x_c, p: Params):
    """K_I of the state (eq. 12)."""
    b, s = p.body, p.soil
    return phys.stress_intensity(_gap(y.x, x_c, p), y.x[0] - y.x[1], s.E_s, s.nu, b.w0, b.l0)


def _stiff_forces(y: WormState, p: Params):
    b, s, sm = p.body, p.soil, p.smoothing
    f_s = phys.stretching_force(y.x, y.lbar, b.EA)
    f_f = phys.friction_force(y.x, y.v, s.E_s, b.h, b.w0, b.l0, s.w_c, s.mu_s, b.lam,
                              sm.eps_v, sm.eps_N, sm.exact)
    return f_s, f_f


def _back_pressure(y: WormState, x_c, p: Params):
    b, s = p.body, p.soil
    return phys.back_pressure(_gap(y.x, x_c, p), y.x[0] - y.x[1], s.E_s, s.nu, b.w0, b.l0,
                              b.h, p.wedge_number)


def forces(t, y: WormState, x_c, p: Params) -> dict:
    """Every force of eq. (17) at one instant [N], and the control u [m/s].

    `stretching` is 𝒱_s (eq. 20), `friction` ℱ_f (eq. 21), both per node;
    `back_pressure` is F_p (eq. 16) on the head.
    """
    f_s, f_f = _stiff_forces(y, p)
    return {"stretching": f_s, "friction": f_f, "back_pressure": _back_pressure(y, x_c, p),
            "u": p.gait(t, y.x, y.v, y.lbar, p.body)}


def vector_field_stiff(t, y: WormState, args) -> WormState:
    """The stiff part: ẋ = v, v̇ = −ℳ⁻¹(𝒱_s − ℱ_f), and the friction dissipation rate."""
    p, _ = args
    f_s, f_f = _stiff_forces(y, p)
    dwork = jnp.stack([0.0, -jnp.sum(f_f * y.v), 0.0])
    return WormState(x=y.v, v=(f_f - f_s) / p.body.node_masses,
                     lbar=jnp.zeros_like(y.lbar), work=dwork)


def vector_field_nonstiff(t, y: WormState, args) -> WormState:
    """The non-stiff part: l̄' = u (eq. 23), −ℳ⁻¹ℱ_p (eq. 22), actuation and back-pressure work."""
    p, x_c = args
    b = p.body
    u = p.gait(t, y.x, y.v, y.lbar, b)
    f_p = _back_pressure(y, x_c, p)
    dv = jnp.zeros_like(y.v).at[0].set(-f_p / b.node_masses[0])
    dwork = jnp.stack([phys.actuation_power(y.x, y.lbar, u, b.EA), 0.0, f_p * y.v[0]])
    return WormState(x=jnp.zeros_like(y.x), v=dv, lbar=u, work=dwork)


def vector_field(t, y: WormState, args) -> WormState:
    """d/dt (x, v, l̄) = (v, −ℳ⁻¹(𝒱_s − ℱ_f + ℱ_p), u) (eqs. 18-23), plus the work rates.

    `args` is `(params, x_c)`.
    """
    a, b = vector_field_stiff(t, y, args), vector_field_nonstiff(t, y, args)
    return jax.tree_util.tree_map(jnp.add, a, b)


def crack_condition(t, y: WormState, args, **kwargs):
    """K_I / K_Ic − 1: the crack event is its upward zero crossing (eq. 12)."""
    p, x_c = args
    return stress_intensity_of(y, x_c, p) / p.soil.K_Ic - 1.0


def crack_jump(y: WormState, p: Params):
    """The new tip x_c(t_{n+1}) where K_I falls to K_Ith (eq. 13)."""
    b, s = p.body, p.soil
    return phys.crack_tip_after_jump(y.x[0], y.x[0] - y.x[1], s.K_Ith, s.E_s, s.nu, b.w0, b.l0)


def _colour_directions(N: int, S: int, n: int) -> np.ndarray:
    """Eight directions in the flat state (x, v, l̄, work): three colours of node
    positions, three of node velocities (entries k ≡ c mod 3: no node's force depends
    on two of them) and two of segment lengths (k ≡ c mod 2: a node feels two segments)."""
    d = np.zeros((8, n))
    for c in range(3):
        d[c, c:N:3] = 1.0
        d[3 + c, N + c:2 * N:3] = 1.0
    for c in range(2):
        d[6 + c, 2 * N + c:2 * N + S:2] = 1.0
    return d


def _band(cols, first: int, colours: int, size: int, shift: int):
    """J[i, i + shift] over rows i of a block with `size` columns, from the products
    `cols[first + c]` with its `colours` colour directions; 0 outside the block.
    Elementwise with static masks: small gathers are slow on a CPU under `vmap`."""
    n = cols.shape[1]
    i = np.arange(n)
    out = jnp.zeros(n, cols.dtype)
    for c in range(colours):
        mask = ((i + shift) % colours == c) & (i + shift >= 0) & (i + shift < size)
        out = out + jnp.where(mask, cols[first + c], 0.0)
    return out


def newton_factor(f, t, flat0, sigma, y0: WormState, args):
    """Solve (σI − J) k = r for this vector field by block elimination, J = ∂f/∂y at
    `flat0` (f the vector field on the flattened state (x, v, l̄, work)). A Rosenbrock
    solver's `factor`.

    Structure used: ẋ = v exactly; the work integrals never feed back; a node's force
    depends on its own and its neighbours' positions and velocities and on its two
    segments' intrinsic lengths; for an open-loop controller l̄' depends on t alone.
    Then k_x = (r_x + k_v)/σ, k_l̄ = r_l̄/σ, and only the N×N Schur complement
    σI − F_v − F_x/σ, tridiagonal, is solved. Its bands and F_l̄ come from eight
    directional derivatives (three colours for x, three for v, two for l̄) instead of
    a full Jacobian.

    The work rows of J are dropped (k_w = r_w/σ): the work integrals are quadratures
    of the state that feed nothing back, so (x, v, l̄) are exactly as with the full
    matrix, while the work integrals lose order. Their energy-balance residual stays
    ~1e-3 (`tests/test_rosenbrock.py`), far below the 5 % that flags a false solution;
    `linear_solve="dense"` keeps the exact rows. A closed-loop controller couples l̄ to
    the state: then the full Jacobian is formed and an (N + S)-square system solved.
    """
    p, _ = args
    N = y0.x.shape[0]
    S = N - 1
    if not p.gait.open_loop:
        return _closed_loop_factor(jax.jacfwd(f)(flat0), sigma, N, S)
    ix, iv, il, iw = _blocks(N, S)
    _, f_lin = jax.linearize(f, flat0)
    dirs = jnp.asarray(_colour_directions(N, S, flat0.shape[0]), flat0.dtype)
    cols = jax.vmap(f_lin)(dirs)[:, iv]                                  # (8, N)
    xl, xd, xu = (_band(cols, 0, 3, N, s) for s in (-1, 0, 1))
    vl, vd, vu = (_band(cols, 3, 3, N, s) for s in (-1, 0, 1))
    l_prev, l_own = (_band(cols, 6, 2, S, s) for s in (-1, 0))       # ∂a_i/∂l̄_{i−1}, ∂a_i/∂l̄_i
    lower, diag, upper = -vl - xl / sigma, sigma - vd - xd / sigma, -vu - xu / sigma

    def solve(r):
        # r is (n,) or (P, n): P right-hand sides share one factorisation.
        rx, rv, rl, rw = r[..., ix], r[..., iv], r[..., il], r[..., iw]
        kl = rl / sigma
        rhs = (rv + _band_product(xl, xd, xu, rx) / sigma
               + l_own * _shift(kl, 0, N) + l_prev * _shift(kl, 1, N))
        cols = rhs.reshape(-1, N).T
        kv = jax.lax.linalg.tridiagonal_solve(lower, diag, upper, cols).T.reshape(rhs.shape)
        kx = (rx + kv) / sigma
        return jnp.concatenate([kx, kv, kl, rw / sigma], axis=-1)

    return solve


def _shift(z, before: int, n: int):
    """z padded with zeros to length n along its last axis, `before` of them in front."""
    pad = [(0, 0)] * (z.ndim - 1) + [(before, n - before - z.shape[-1])]
    return jnp.pad(z, pad)


def _band_product(lower, diag, upper, z):
    """(tridiagonal matrix) @ z from its bands."""
    n = z.shape[-1]
    return diag * z + lower * _shift(z[..., :-1], 1, n) + upper * _shift(z[..., 1:], 0, n)


def _blocks(N: int, S: int):
    """Slices of x, v, l̄ and the work integrals in the flattened state."""
    return slice(0, N), slice(N, 2 * N), slice(2 * N, 2 * N + S), slice(2 * N + S, None)


def _closed_loop_factor(jac, sigma, N, S):
    """`newton_factor` for a closed-loop controller: an (N + S)-square LU, work rows kept."""
    ix, iv, il, iw = _blocks(N, S)
    Fx, Fv, Fl = jac[iv, ix], jac[iv, iv], jac[iv, il]
    Wx, Wv, Wl = jac[iw, ix], jac[iw, iv], jac[iw, il]
    Ux, Uv, Ul = jac[il, ix], jac[il, iv], jac[il, il]
    eye = jnp.eye(N, dtype=jac.dtype)
    top = jnp.concatenate([sigma * eye - Fv - Fx / sigma, -Fl], axis=1)
    bottom = jnp.concatenate([-Uv - Ux / sigma, sigma * jnp.eye(S, dtype=jac.dtype) - Ul], axis=1)
    lu = lu_factor(jnp.concatenate([top, bottom], axis=0))

    def solve(r):
        if r.ndim == 2:                      # (P, n): the forward sensitivities' stages
            return jax.vmap(solve)(r)
        rx, rv, rl, rw = r[ix], r[iv], r[il], r[iw]
        kvl = lu_solve(lu, jnp.concatenate([rv + Fx @ rx / sigma, rl + Ux @ rx / sigma]))
        kv, kl = kvl[:N], kvl[N:]
        kx = (rx + kv) / sigma
        kw = (rw + Wx @ kx + Wv @ kv + Wl @ kl) / sigma
        return jnp.concatenate([kx, kv, kl, kw])

    return solve
