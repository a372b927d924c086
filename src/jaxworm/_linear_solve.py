"""The Newton matrix of a Rosenbrock step, σI − J, factorised: dense, or by the model's structure.

A Rosenbrock solver (`_rosenbrock.AbstractRosenbrock`) takes a `factor(f, t, flat0, σ, y0,
args)` that factorises σI − J, J = ∂f/∂y at the flattened state `flat0`, and returns the
solve r ↦ (σI − J)⁻¹ r for r of shape (n,) or (P, n) (the forward sensitivities' stages).

- `dense_factor`: the full Jacobian by `jax.jacfwd` and a dense LU; any vector field.
- `structured_factor`: block elimination for the worm's state (x, v, l̄, work), the
  inverse of an N-square tridiagonal matrix from eight directional derivatives, formed
  once per step and applied at every stage
  (`Numerics(linear_solve="structured")`, the default of the Rodas4 presets).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jax.scipy.linalg import lu_factor, lu_solve

from ._dynamics import actuation_work_of_power, control_rate, reads_crack, sensors_of
from ._feedback import AbstractFeedbackController
from ._physics import actuation_power, segment_lengths

__all__ = ["dense_factor", "structured_factor", "structured_lanes_factor", "FACTORS"]


def dense_factor(f, t, flat0, sigma, y0, args):
    """LU of the Newton matrix σI − J, J = ∂f/∂y at `flat0` (the flattened state);
    returns its solve, for right-hand sides (n,) or (P, n)."""
    jac = jax.jacfwd(f)(flat0)
    n = jac.shape[0]
    lu = lu_factor(sigma * jnp.eye(n, dtype=jac.dtype) - jac)
    return lambda r: lu_solve(lu, r) if r.ndim == 1 else lu_solve(lu, r.T).T


def _colour_directions(N: int, S: int, n: int) -> np.ndarray:
    """Eight directions in the flat state (x, v, l̄, work): three colours of node
    positions, three of node velocities (entries k ≡ c mod 3: no node's force depends
    on two of them) and two of segment lengths (k ≡ c mod 2: a node feels two segments)."""
    d = np.zeros((8, n))
    for c in range(3):
        d[c, c:N:3] = 1.0
        d[3 + c, N + c : 2 * N : 3] = 1.0
    for c in range(2):
        d[6 + c, 2 * N + c : 2 * N + S : 2] = 1.0
    return d


def _band(cols, first: int, colours: int, size: int, shift: int):
    """J[i, i + shift] over rows i of a block with `size` columns, from the products
    `cols[first + c]` with its `colours` colour directions; 0 outside the block.
    Elementwise with static masks: small gathers are slow on a CPU under `vmap`."""
    n = cols[0].shape[-1]
    i = np.arange(n)
    out = jnp.zeros(n, cols[0].dtype)
    for c in range(colours):
        mask = ((i + shift) % colours == c) & (i + shift >= 0) & (i + shift < size)
        out = out + jnp.where(mask, cols[first + c], 0.0)
    return out


def structured_factor(f, t, flat0, sigma, y0, args, lanes: bool = False):
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
    `linear_solve="dense"` keeps the exact rows.

    A closed-loop controller (`p.gait.open_loop` False) couples l̄ to the state: the
    force rows keep their bands (u does not enter them), the rows of l̄ (∂u/∂y) and of
    the actuation work come from the controller alone (`_control_rows`), and the
    tridiagonal solve is bordered by an S-square Schur complement (`_closed_loop_solve`).
    """
    p, _ = args
    N = y0.x.shape[0]
    if N < 3:
        # One segment: the state is a handful of numbers, and the work rows dropped below
        # cost the work integrals their order at the long steps such a body takes (the
        # energy balance then fails): the full matrix, by LU.
        return dense_factor(f, t, flat0, sigma, y0, args)
    S = N - 1
    ix, iv, il, iw = _blocks(N, S)
    _, f_lin = jax.linearize(f, flat0)
    dirs = _colour_directions(N, S, flat0.shape[0])
    # Three vmaps (x, v and l̄ colours), so that each result stays small (`SMALL`).
    cols = [row for a, b in ((0, 3), (3, 6), (6, 8)) for row in jax.vmap(f_lin)(dirs[a:b])[:, iv]]
    xl, xd, xu = (_band(cols, 0, 3, N, s) for s in (-1, 0, 1))
    vl, vd, vu = (_band(cols, 3, 3, N, s) for s in (-1, 0, 1))
    l_prev, l_own = (_band(cols, 6, 2, S, s) for s in (-1, 0))  # ∂a_i/∂l̄_{i−1}, ∂a_i/∂l̄_i
    bands = -vl - xl / sigma, sigma - vd - xd / sigma, -vu - xu / sigma
    tridiagonal = (_thomas_factor if lanes else _tridiagonal_factor)(*bands)
    if not p.gait.open_loop:
        U, W = _control_rows(t, flat0, y0, args, (ix, iv, il))
        return _closed_loop_solve(tridiagonal, (xl, xd, xu), (l_prev, l_own), U, W, sigma, N, S)

    def solve(r):
        # r is (n,) or (P, n): P right-hand sides share one factorisation.
        rx, rv, rl, rw = r[..., ix], r[..., iv], r[..., il], r[..., iw]
        kl = rl / sigma
        rhs = (
            rv
            + _band_product(xl, xd, xu, rx) / sigma
            + l_own * _shift(kl, 0, N)
            + l_prev * _shift(kl, 1, N)
        )
        kv = tridiagonal(rhs)
        kx = (rx + kv) / sigma
        return jnp.concatenate([kx, kv, kl, rw / sigma], axis=-1)

    return solve


def _tridiagonal_factor(lower, diag, upper):
    """The solve z ↦ T⁻¹ z along the last axis of z, T the tridiagonal matrix with
    these bands (lower[0] and upper[-1] unused). T⁻¹ is formed once
    (`_tridiagonal_inverse`), and every stage of the step applies it as a
    product and a sum, which XLA fuses with the rest of a lone stage. Under `vmap`
    that product was measured slower than a library solve per stage:
    `_thomas_factor` serves lanes.

    T⁻¹ is formed and applied in blocks of columns of at most `SMALL` entries: XLA's
    CPU runtime runs a loop body's kernels one after another only while every buffer
    they use holds at most 512 bytes, and hands them to a thread pool past it, which
    costs a step of small kernels more than it gains (`benchmarks/loop_buffers.py`).
    The worm's flattened state (3N + 3 values) passes that size itself from N = 21 on;
    a larger body then takes T⁻¹ whole, since the blocks would only add kernels."""
    n = diag.shape[-1]
    width = n if 3 * n + 3 > SMALL else max(1, SMALL // n)
    blocks = [(a, min(a + width, n)) for a in range(0, n, width)]
    columns = [_tridiagonal_inverse(lower, diag, upper, a, b) for a, b in blocks]

    def solve(z):
        return sum(_times(inverse, z[..., a:b]) for (a, b), inverse in zip(blocks, columns))

    return solve


#: The most float64 entries an array of a solver step should hold (512 bytes, see
#: `_tridiagonal_factor`).
SMALL = 64


def _tridiagonal_inverse(lower, diag, upper, start: int = 0, stop: int | None = None):
    """Columns start..stop of T⁻¹ from T's bands (all by default): on a CPU by LAPACK's
    tridiagonal solve of the identity's columns; on other platforms by Thomas's
    elimination written out in JAX (`_thomas_factor`). The GPU library call (cuSPARSE
    gtsv2) solves a batch one system at a time, so under `vmap` its cost grows with the
    number of lanes at every step."""
    return jax.lax.platform_dependent(
        lower,
        diag,
        upper,
        cpu=lambda lo, d, up: _library_inverse(lo, d, up, start, stop),
        default=lambda lo, d, up: _thomas_inverse(lo, d, up, start, stop),
    )


def _library_inverse(lower, diag, upper, start: int = 0, stop: int | None = None):
    """Columns start..stop of T⁻¹ by `jax.lax.linalg.tridiagonal_solve`."""
    return jax.lax.linalg.tridiagonal_solve(lower, diag, upper, _unit_columns(diag, start, stop))


def _unit_columns(diag, start: int, stop: int | None):
    """Columns start..stop of the identity, formed at that size (`SMALL`)."""
    n = diag.shape[-1]
    columns = np.arange(n)[start:stop]
    return (np.arange(n)[:, None] == columns[None, :]).astype(diag.dtype)


def _thomas_inverse(lower, diag, upper, start: int = 0, stop: int | None = None):
    """Columns start..stop of T⁻¹ by `_thomas_factor`: elementwise code only."""
    rows = jnp.swapaxes(_unit_columns(diag, start, stop), 0, 1)
    # Row i of the solve of these rows is T⁻¹ e_i, the i-th column of T⁻¹.
    return jnp.swapaxes(_thomas_factor(lower, diag, upper)(rows), -1, -2)


def _thomas_factor(lower, diag, upper):
    """`_tridiagonal_factor` for vmapped lanes: Thomas's elimination, its pivots formed
    once per step and written out over the (static, small) size, so that every stage's
    solve is elementwise code across the lanes, which XLA fuses. (For a lone solve the
    same code is slower than the product with T⁻¹: scalar operations XLA does not fuse.)
    No pivoting: it agrees with a pivoted dense LU on this model's Newton matrices
    (`tests/test_rosenbrock.py`), and a zero pivot makes the step non-finite, which the
    step control rejects."""
    n = diag.shape[-1]
    inv_m, c = [1.0 / diag[..., 0]], []
    for i in range(1, n):
        c.append(upper[..., i - 1] * inv_m[i - 1])
        inv_m.append(1.0 / (diag[..., i] - lower[..., i] * c[i - 1]))

    def solve(z):
        g = [z[..., 0] * inv_m[0]]
        for i in range(1, n):
            g.append((z[..., i] - lower[..., i] * g[i - 1]) * inv_m[i])
        x = [g[n - 1]]
        for i in range(n - 2, -1, -1):
            x.append(g[i] - c[i] * x[-1])
        return jnp.stack(x[::-1], axis=-1)

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


def _from_bands(bands_and_shifts, rows: int, cols: int):
    """The dense (rows × cols) matrix with band[i] at (i, i + shift) for each (band,
    shift), entries outside dropped. Products with static masks: scatters into small
    matrices are slow on a CPU."""
    out = jnp.zeros((rows, cols))
    for band, shift in bands_and_shifts:
        mask = np.eye(rows, cols, k=shift)
        out = out + band[:, None] * mask
    return out


def _closed_loop_solve(tridiagonal, x_bands, l_bands, U, W, sigma, N, S):
    """`structured_factor` for a closed-loop controller, whose rows U = ∂u/∂y couple
    l̄ to the state; W = (dw/dP, ∂P/∂y) the work rows of J, an outer product
    (`_control_rows`).

    With k_x = (r_x + k_v)/σ and k_l̄ from its own rows, the stage is the (N + S)-square
    system [[A, −F_l̄], [C, D]] (k_v, k_l̄) = (r_v + F_x r_x/σ, r_l̄ + U_x r_x/σ),
    A = σI − F_v − F_x/σ the open loop's tridiagonal matrix (`tridiagonal` its solve),
    C = −U_v − U_x/σ, D = σI − U_l̄. It is solved by block elimination once per step:
    Z = A⁻¹F_l̄ and the inverse of the S-square Schur complement D + C Z
    (`_gauss_jordan`); every stage then takes one tridiagonal solve and small
    products. k_w = (r_w + dw/dP (∂P/∂y · k))/σ (the work integrals feed nothing back)."""
    ix, iv, il, iw = _blocks(N, S)
    (xl, xd, xu), (l_prev, l_own) = x_bands, l_bands
    Fl = _from_bands(((l_own, 0), (l_prev, -1)), N, S)
    Ux, Uv, Ul = U
    weights, (Wx, Wv, Wl) = W
    C = -Uv - Ux / sigma
    Z = jnp.swapaxes(tridiagonal(jnp.swapaxes(Fl, 0, 1)), 0, 1)  # A⁻¹ F_l̄, (N, S)
    schur = sigma * jnp.eye(S, dtype=Ul.dtype) - Ul + jnp.sum(C[:, :, None] * Z[None], axis=1)
    schur_inverse = _gauss_jordan(schur)
    # dp = W_x·k_x + W_v·k_v + W_l̄·k_l̄ with k_x = (r_x + k_v)/σ, as one sum.
    dp_weights = jnp.concatenate([Wx / sigma, Wx / sigma + Wv, Wl])

    def solve(r):
        # r is (n,) or (P, n): P right-hand sides share one factorisation.
        rx, rv, rl, rw = r[..., ix], r[..., iv], r[..., il], r[..., iw]
        a_r = tridiagonal(rv + _band_product(xl, xd, xu, rx) / sigma)  # A⁻¹ r_v'
        kl = _times(schur_inverse, rl + _times(Ux, rx) / sigma - _times(C, a_r))
        kv = a_r + _times(Z, kl)
        kx = (rx + kv) / sigma
        dp = jnp.sum(dp_weights * jnp.concatenate([rx, kv, kl], axis=-1), -1)
        kw = (rw + weights * dp[..., None]) / sigma
        return jnp.concatenate([kx, kv, kl, kw], axis=-1)

    return solve


def _control_rows(t, flat0, y0, args, column_blocks):
    """The rows of J = ∂f/∂y that a closed-loop control u drives, each as its blocks in
    `column_blocks` (x, v, l̄): U = ∂u/∂y, the rows of l̄, and W, the work integrals'.

    U comes by reverse mode through the controller alone (`_feedback_rows` for a
    feedback controller, `control_rate` for a gait u(t, x, v, l̄)): one product per
    segment, where directional derivatives need one per state entry, each through the
    whole vector field. The work integrals that u moves are functions of one scalar,
    the actuation power P = ∂V/∂l̄·u (`actuation_work_of_power`: P and |P|), so W is
    (dw/dP, ∂P/∂y): the gradient of P by the chain rule through u, and the 4 weights
    dw/dP, whose outer product is the rows of J. The friction and back-pressure rows
    are dropped, as for an open-loop gait (`structured_factor`): (x, v, l̄) do not see
    them. Dropping the actuation rows as well put the energy balance of a trained
    policy 5-8 % off."""
    p, x_c = args
    _, unravel = ravel_pytree(y0)
    y = unravel(flat0)
    if isinstance(p.gait, AbstractFeedbackController):
        u, U = _feedback_rows(t, y, x_c, p)
    else:
        u = control_rate(t, y, x_c, p)
        du = jax.jacrev(lambda yf: control_rate(t, unravel(yf), x_c, p))(flat0)
        U = tuple(du[:, cols] for cols in column_blocks)
    power, (p_x, p_l, p_u) = jax.value_and_grad(actuation_power, argnums=(0, 1, 2))(
        y.x, y.lbar, u, p.body.EA
    )
    weights = jax.jacfwd(actuation_work_of_power)(power)  # (4,): dw/dP
    Ux, Uv, Ul = (jnp.sum(p_u[:, None] * b, axis=0) for b in U)  # P_u · U
    return U, (weights, (p_x + Ux, Uv, p_l + Ul))


def _feedback_rows(t, y, x_c, p):
    """u and U = ∂u/∂(x, v, l̄) of an `AbstractFeedbackController` by the chain rule
    through its sensors (`sensors_of`): ∂u/∂(v, l, l̄) by reverse mode through `control`
    alone, then l_k = x_k − x_{k+1}; for a controller that reads the crack
    (`reads_crack`), ∂u/∂(F_p, K_I/K_Ic) by forward mode (two scalar directions) times
    the crack sensors' derivatives in the head's two nodes x_1, x_2 (eqs. 12, 16).
    Forward mode for those two: reverse mode through them as well made a reflex's step
    slower (`benchmarks/closed_loop_cost.py`)."""
    s = sensors_of(t, y, x_c, p)

    def u_of(sensors):
        return p.gait.control(sensors, p.body)

    def u_of_vectors(v, lengths, lbar):
        return u_of(eqx.tree_at(lambda q: (q.v, q.lengths, q.lbar), s, (v, lengths, lbar)))

    u = u_of(s)
    Uv, U_len, Ul = jax.jacrev(u_of_vectors, argnums=(0, 1, 2))(s.v, s.lengths, s.lbar)
    _, lengths_vjp = jax.vjp(segment_lengths, y.x)
    Ux = jax.vmap(lambda row: lengths_vjp(row)[0])(U_len)
    if not reads_crack(p):
        return u, (Ux, Uv, Ul)

    def u_of_crack(crack):
        return u_of(eqx.tree_at(lambda q: (q.back_pressure, q.stress_ratio), s, crack))

    U_crack = jnp.stack(jax.jacfwd(u_of_crack)((s.back_pressure, s.stress_ratio)), axis=1)
    # (S, 2): ∂u/∂F_p, ∂u/∂(K_I/K_Ic)

    def crack_of_head(x_head):
        q = sensors_of(t, eqx.tree_at(lambda q: q.x, y, y.x.at[:2].set(x_head)), x_c, p)
        return jnp.stack([q.back_pressure, q.stress_ratio])

    crack_x = jax.jacfwd(crack_of_head)(y.x[:2])  # (2, 2): ∂(F_p, K_I/K_Ic)/∂(x_1, x_2)
    Ux = Ux.at[:, :2].add(_times(crack_x.T, U_crack))
    return u, (Ux, Uv, Ul)


def _gauss_jordan(matrix):
    """The inverse of a small square matrix by Gauss-Jordan elimination in place,
    written out over its static size, without pivoting: elementwise code that XLA
    fuses, where a library inverse is a call per step. Used for the Schur complement
    of the closed-loop solve, σI − ∂u/∂l̄ + O(1/σ) for the small steps where the Newton
    matrix is near σI; a zero pivot makes the step non-finite, which the step control
    rejects, and `tests/test_rosenbrock.py` checks it against a pivoted dense LU.

    In place, so that no array grows past the matrix itself: XLA's CPU runtime runs
    the thunks of a loop body one after another only while every buffer they use holds
    at most 512 bytes (64 float64); past that it hands them to a thread pool, which
    costs a step of small kernels more than it gains (`benchmarks/loop_buffers.py`)."""
    n = matrix.shape[-1]
    a = matrix
    rows = np.arange(n)[:, None]
    cols = np.arange(n)[None, :]
    for k in range(n):
        p = 1.0 / a[k, k]
        pivot_row = jnp.where(cols[0] == k, p, a[k] * p)
        factor = jnp.where(rows[:, 0] == k, 0.0, a[:, k])
        a = jnp.where(cols == k, -factor[:, None] * p, a) - factor[:, None] * jnp.where(
            cols == k, 0.0, pivot_row
        )
        a = jnp.where(rows == k, pivot_row, a)
    return a


def _times(matrix, z):
    """matrix @ z along the last axis of z, as a product and a sum, which XLA fuses
    with what surrounds it in a lone solve."""
    return jnp.sum(matrix * z[..., None, :], axis=-1)


def structured_lanes_factor(f, t, flat0, sigma, y0, args):
    """`structured_factor` written for vmapped lanes: its tridiagonal solve is
    `_thomas_factor` (the closed-loop solve takes it too)."""
    return structured_factor(f, t, flat0, sigma, y0, args, lanes=True)


#: The factorisation of each `Numerics.linear_solve`.
FACTORS = {
    "structured": structured_factor,
    "structured_lanes": structured_lanes_factor,
    "dense": dense_factor,
}
