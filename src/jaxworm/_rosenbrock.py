"""Rosenbrock (linearly implicit) solvers for diffrax, written for small stiff systems.

diffrax's implicit Runge-Kutta solvers (Kvaerno, KenCarp) solve a nonlinear system per
stage with an iterative root finder; on this model the iteration, not the vector field,
costs almost all of each step (~40 µs against ~1 µs for a vector-field evaluation).
A Rosenbrock method replaces the iteration by one exact Jacobian and one LU
factorisation per step, then one triangular solve per stage:

    (I/(γh) − J) k_i = f(t + α_i h, y + Σ_j a_ij k_j) + Σ_j (c_ij / h) k_j + h d_i ∂f/∂t,
    y_1 = y + Σ_i m_i k_i,   error estimate Σ_i e_i k_i

(Hairer & Wanner, *Solving ODEs II*, §IV.7, eq. 7.4' with the transformed variables).
The state pytree is flattened for the dense linear algebra (the model has 3N + 3
unknowns). Dense output is RODAS's own cubic from the stages (`interpolant="rodas"`,
no extra evaluation) or the cubic Hermite from f at both ends of the step
(`"hermite"`, one more evaluation of f per step).

Its steps refuse to be differentiated (`ForwardOnlyError`) instead of returning a wrong
gradient; `jaxworm.simulate` differentiates a Rodas4 solve by forward sensitivities
integrated with the state instead (`jaxworm._sensitivity`). For d v̄/dA at t1 = 0.3 s
(`accurate` gives 0.776), differentiating the steps of `fast` gives 0.598 in forward
mode and 0.756 in reverse mode, and the dense linear solve gives 0.810 in both. The
derivative of a Rosenbrock step differentiates its Jacobian: second derivatives of the
smoothed friction, ~1/ε_v² large, taken over steps that jump the elastic ringing (the
positions norm). That derivative is far from the sensitivity, and it is so
ill-conditioned that rounding differences between the forward- and reverse-mode
programs change it by 25 %. Freezing the Jacobian for differentiation
(`stop_gradient`: a W-method on the sensitivities) gave 0.719; the full error norm gave
0.772, but that resolves the ringing, at the cost of the speed that is the point of this
solver. The Kvaerno solvers differentiate the converged implicit stages instead, and
their derivatives converge.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, ArrayLike, Bool, Float, PyTree

from ._linear_solve import dense_factor
from ._physics import Scalar

__all__ = ["Rodas4", "RosenbrockTableau", "hermite_slopes", "looped_stages"]


_NOT_DIFFERENTIABLE = (
    "the Rosenbrock solver's steps (solver='Rodas4', preset 'fast') are forward-only: the "
    "derivative of its steps, which jump the elastic ringing, was measured 23 % off the "
    "sensitivity (docs: Gradients). jaxworm.simulate differentiates a Rodas4 solve by "
    "forward sensitivities instead; for a solve of your own, use a Kvaerno solver."
)


class ForwardOnlyError(TypeError):
    """Raised when the steps of a forward-only solver (Rodas4) are differentiated."""


def refusing(error: type[Exception], message: str) -> Callable[[Array], Array]:
    """An identity that raises `error(message)` when differentiated, so that no wrong
    derivative goes unnoticed."""

    @jax.custom_jvp
    def identity(x):
        return x

    @identity.defjvp
    def identity_jvp(primals, tangents):
        raise error(message)

    return identity


_forward_only = refusing(ForwardOnlyError, _NOT_DIFFERENTIABLE)


class RosenbrockTableau(eqx.Module):
    """Coefficients of an s-stage Rosenbrock method in Hairer-Wanner's transformed form.

    `a`, `c` strictly lower triangular (s, s); `alpha` stage times and `d` the
    ∂f/∂t weights (s,); `m` solution and `e` error weights (s,); `gamma` the diagonal;
    `dense` (2, s) the weights of the continuous extension's two stage sums q₂, q₃:
    y(t₀ + θh) = (1 − θ) y₀ + θ (y₁ + (1 − θ)(q₂ + θ q₃)).
    """

    gamma: float
    alpha: Float[np.ndarray, " s"]
    d: Float[np.ndarray, " s"]
    a: Float[np.ndarray, "s s"]
    c: Float[np.ndarray, "s s"]
    m: Float[np.ndarray, " s"]
    e: Float[np.ndarray, " s"]
    dense: Float[np.ndarray, "2 s"]
    order: int


def _lower(rows: Sequence[Sequence[float]], s: int) -> Float[np.ndarray, "s s"]:
    """The (s, s) matrix with `rows` from the left of its first rows, zero elsewhere."""
    out = np.zeros((s, s))
    for i, row in enumerate(rows):
        out[i, : len(row)] = row
    return out


# RODAS (Hairer & Wanner 1996, rodas.f METH = 1): order 4, embedded order 3, L-stable,
# stiffly accurate. The fifth and sixth stage arguments are the embedded and the final
# solution, so m_i = a_6i and the error estimate is the last stage alone.
_A5 = [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.6878860361058950]
RODAS4 = RosenbrockTableau(
    gamma=0.25,
    alpha=np.array([0.0, 0.386, 0.21, 0.63, 1.0, 1.0]),
    d=np.array([0.25, -0.1043, 0.1035, -0.03620000000000023, 0.0, 0.0]),
    a=_lower(
        [
            [],
            [1.544],
            [0.9466785280815826, 0.2557011698983284],
            [3.314825187068521, 2.896124015972201, 0.9986419139977817],
            _A5,
            _A5 + [1.0],
        ],
        6,
    ),
    c=_lower(
        [
            [],
            [-5.6688],
            [-2.430093356833875, -0.2063599157091915],
            [-0.1073529058151375, -9.594562251023355, -20.47028614809616],
            [7.496443313967647, -10.24680431464352, -33.99990352819905, 11.70890893206160],
            [
                8.083246795921522,
                -7.981132988064893,
                -31.52159432874371,
                16.31930543123136,
                -6.058818238834054,
            ],
        ],
        6,
    ),
    m=np.array(_A5 + [1.0, 1.0]),
    e=np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
    # The third-order continuous extension (rodas.f, d_ij of its coefficient routine).
    dense=np.array(
        [
            [
                10.12623508344586,
                -7.487995877610167,
                -34.80091861555747,
                -7.992771707568823,
                1.025137723295662,
                0.0,
            ],
            [
                -0.6762803392801253,
                6.087714651680015,
                16.43084320892478,
                24.76722511418386,
                -6.594389125716872,
                0.0,
            ],
        ]
    ),
    order=4,
)


def hermite_slopes(y0, y1, q2, q3):
    """(h y'(t₀), h y'(t₁)) of the continuous extension (see `RosenbrockTableau`).

    A cubic is fixed by its values and slopes at both ends, so diffrax's cubic Hermite
    interpolation with these slopes is the extension itself.
    """
    dy = y1 - y0
    return dy + q2, dy - q2 - q3


def looped_stages(tab, h, t0, z0, f0, f_t, f, solve):
    """The stages of one Rosenbrock step as a loop; returns (z1, its error estimate,
    the continuous extension's stage sums (q₂, q₃)).

    `z0` is a pytree of flat arrays, `f0` = f(t0, z0) and `f_t` = ∂f/∂t there, `f(t, z)`
    the vector field and `solve(r)` the stage solve (σI − J)⁻¹ r. Stage 0 takes `f0`;
    stages 1..s−1 run as one `fori_loop`, so XLA compiles one stage body instead of s.

    Each pass of the loop costs a fixed overhead on a CPU, and the stacked stages
    (s, n) can pass XLA's 512-byte threshold past which a loop body's kernels are
    handed to a thread pool (`benchmarks/loop_buffers.py`), so the forward steps run
    unrolled; the forward sensitivities' step, with the state, runs looped and compiles
    faster (`benchmarks/gradient_cost.py`).
    The stage sums are products and sums, which XLA fuses (`tensordot` ran slower
    under `vmap`).
    """
    s = len(tab.alpha)
    a, c, alpha, d, m, e = (jnp.asarray(v) for v in (tab.a, tab.c, tab.alpha, tab.d, tab.m, tab.e))
    tmap = jax.tree_util.tree_map

    def dot(w, K):  # Σ_j w_j K_j, leaf by leaf
        return tmap(lambda k: jnp.sum(w.reshape((-1,) + (1,) * (k.ndim - 1)) * k, 0), K)

    def stage(i, fi, K):
        rhs = tmap(lambda fi_, ck, ft: fi_ + ck + (h * d[i]) * ft, fi, dot(c[i] / h, K), f_t)
        return tmap(lambda K_, k: K_.at[i].set(k), K, solve(rhs))

    K = stage(0, f0, tmap(lambda z: jnp.zeros((s,) + z.shape, z.dtype), z0))

    def body(i, K):
        return stage(i, f(t0 + alpha[i] * h, tmap(jnp.add, z0, dot(a[i], K))), K)

    K = jax.lax.fori_loop(1, s, body, K)
    q = jnp.asarray(tab.dense)
    return tmap(jnp.add, z0, dot(m, K)), dot(e, K), (dot(q[0], K), dot(q[1], K))


class AbstractRosenbrock(diffrax.AbstractAdaptiveSolver):
    """A Rosenbrock method on an `ODETerm`, with an exact (forward-mode) Jacobian.

    `factor(f, t, y, σ, y0, args)` factorises σI − J, J = ∂f/∂y at the flattened
    state `y` (f the vector field at time t), and returns the solve r ↦ (σI − J)⁻¹ r
    for r of shape (n,) or (P, n) (the forward sensitivities' stages);
    the default forms J by `jax.jacfwd` and takes a dense LU. A model that knows its
    Jacobian's structure passes a cheaper one. `looped`: run the stages as one loop
    (`looped_stages`: faster for a costly step) instead of unrolled. `interpolant`:
    the dense output (on which events are located), `"rodas"` the method's own cubic
    from the stages or `"hermite"` the cubic from f at both ends (one more f per step).
    """

    factor: Callable = eqx.field(static=True, default=dense_factor)
    looped: bool = eqx.field(static=True, default=False)
    interpolant: str = eqx.field(static=True, default="rodas")

    tableau: ClassVar[RosenbrockTableau]
    term_structure: ClassVar = diffrax.AbstractTerm
    # The Hermite cubic with the extension's end slopes is the extension (`hermite_slopes`).
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation

    def __check_init__(self):
        if self.interpolant not in ("rodas", "hermite"):
            raise ValueError(f"interpolant = {self.interpolant!r}: need 'rodas' or 'hermite'")

    def order(self, terms: diffrax.AbstractTerm) -> int:
        return self.tableau.order

    def error_order(self, terms: diffrax.AbstractTerm) -> int:
        return self.tableau.order

    def init(
        self,
        terms: diffrax.AbstractTerm,
        t0: Scalar,
        t1: Scalar,
        y0: PyTree[Array],
        args: Any,
    ) -> None:
        return None

    def func(
        self, terms: diffrax.AbstractTerm, t0: Scalar, y0: PyTree[Array], args: Any
    ) -> PyTree[Array]:
        return terms.vf(t0, y0, args)

    def step(
        self,
        terms: diffrax.AbstractTerm,
        t0: Scalar,
        t1: Scalar,
        y0: PyTree[Array],
        args: Any,
        solver_state: None,
        made_jump: Bool[ArrayLike, ""],
    ) -> tuple[PyTree[Array], PyTree[Array], dict[str, PyTree[Array]], None, diffrax.RESULTS]:
        del solver_state, made_jump
        tab = self.tableau
        # A zero-length step (a finished lane of a vmapped solve still runs the loop
        # body, masked) would divide by zero; its result is discarded, so step a
        # harmless 1 µs instead and keep everything finite.
        zero = t1 == t0
        h = jnp.where(zero, 1e-6, t1 - t0)
        t1 = jnp.where(zero, t0 + h, t1)
        flat0, unravel = ravel_pytree(y0)

        def f(t, yf):
            return ravel_pytree(terms.vf(t, unravel(yf), args))[0]

        f0, f_t = jax.jvp(lambda t: f(t, flat0), (t0,), (jnp.ones_like(t0),))
        solve = self.factor(lambda yf: f(t0, yf), t0, flat0, 1.0 / (tab.gamma * h), y0, args)

        if self.looped:
            y1f, errf, (q2, q3) = looped_stages(tab, h, t0, flat0, f0, f_t, f, solve)
        else:
            ks = []
            for i in range(len(tab.alpha)):
                if i == 0:
                    fi = f0
                else:
                    yi = flat0 + sum(tab.a[i, j] * ks[j] for j in range(i) if tab.a[i, j] != 0)
                    fi = f(t0 + tab.alpha[i] * h, yi)
                rhs = fi + sum((tab.c[i, j] / h) * ks[j] for j in range(i) if tab.c[i, j] != 0)
                if tab.d[i] != 0:
                    rhs = rhs + (h * tab.d[i]) * f_t
                ks.append(solve(rhs))
            y1f = flat0 + sum(w * k for w, k in zip(tab.m, ks) if w != 0)
            errf = sum(w * k for w, k in zip(tab.e, ks) if w != 0)
            q2, q3 = (sum(w * k for w, k in zip(row, ks) if w != 0) for row in tab.dense)
        # A non-finite step gets an infinite error, so the step-size controller rejects it.
        errf = jnp.where(jnp.all(jnp.isfinite(y1f)), errf, jnp.inf)
        y1f = _forward_only(jnp.where(zero, flat0, y1f))
        errf = jnp.where(zero, 0.0, errf)
        if self.interpolant == "hermite":
            k0, k1 = f0 * h, f(t1, y1f) * h
        else:
            k0, k1 = hermite_slopes(flat0, y1f, q2, q3)
        k0, k1 = (jnp.where(zero, 0.0, k) for k in (k0, k1))
        y1 = unravel(y1f)
        dense_info = dict(y0=y0, y1=y1, k0=unravel(k0), k1=unravel(k1))
        return y1, unravel(errf), dense_info, None, diffrax.RESULTS.successful


class Rodas4(AbstractRosenbrock):
    """RODAS: 4th-order, L-stable, stiffly accurate Rosenbrock method with a 3rd-order
    embedded error estimate (Hairer & Wanner). Six stages, one Jacobian and one LU
    factorisation per step, no nonlinear iteration."""

    tableau: ClassVar[RosenbrockTableau] = RODAS4
