"""Soil identification: recover soil parameters from an observed head trajectory.

Given the head position x_1 observed at times t_j (a camera, say, with noise), find the
soil (E_s, K_Ic, μ_s by default) whose simulated head best matches it, by gradient-based
least squares through the solve and its crack events:

    minimise  (1/J) Σ_j (x_1(t_j; θ) − x_1^obs(t_j))² / σ_ref²,

with `jaxworm.optimise` (bounded by the sigmoid reparametrisation, several starts).
σ_ref = 1e-4 m only scales the printed values (Adam is scale-free).

```python
import numpy as np, jaxworm as jw
ts = np.linspace(0.1, 5.0, 50)
x1 = jw.observe(jw.Params().replace(delta=-np.pi / 4), ts, noise=1e-4, seed=0)
res = jw.identify(ts, x1, {"E_s": (1e5, 2e5), "K_Ic": (210.0, 320.0), "mu_s": (0.2, 0.45)},
                  base=jw.Params().replace(delta=-np.pi / 4), steps=30)
res.best_theta
```
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from ._numerics import PRESETS, Numerics
from ._optimise import OptimiseResult, optimise
from ._params import Params
from ._solve import simulate
from ._validation import check_range, to_float

__all__ = ["observe", "identify", "head_misfit", "MISFIT_SCALE"]

#: Position scale [m] of the misfit (it divides the squared residuals).
MISFIT_SCALE = 1e-4


def observe(
    params: Params,
    ts: Float[ArrayLike, " J"],
    noise: float = 0.0,
    seed: int = 0,
    numerics: Numerics = PRESETS["default"],
) -> Float[np.ndarray, " J"]:
    """The head position x_1 [m] of a simulated worm at the times `ts` [s], plus Gaussian
    noise of standard deviation `noise` [m] (a synthetic observation)."""
    ts = np.asarray(ts, dtype=np.float64)
    if ts.ndim != 1 or ts.size == 0 or not np.all(np.diff(ts) > 0) or ts[0] < 0:
        raise ValueError("option ts: need increasing times >= 0 [s]")
    check_range("noise", to_float(noise), lambda v: v >= 0, ">= 0 [m]", kind="option")
    try:
        rng = np.random.default_rng(seed)
    except (TypeError, ValueError) as e:
        raise ValueError(
            f"option seed = {seed!r}: not a seed numpy.random.default_rng takes ({e})"
        ) from None
    r = simulate(params, float(ts[-1]), numerics, ts=jnp.asarray(ts))
    if int(r.status) != 0:
        raise ValueError(f"the observed run ended with status {r.status_name}")
    assert r.trajectory is not None  # dense output at `ts` was asked for
    x1 = np.asarray(r.trajectory.x[:, 0])
    return x1 + noise * rng.standard_normal(x1.shape)


class head_misfit(eqx.Module):
    """The objective `f(result)`: mean squared head residual over the observation times,
    in units of MISFIT_SCALE² (needs a result with dense output at those times).

    A Module, so the observation is an array leaf: fits to other data of the same shape
    reuse the compiled program."""

    observed: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=jnp.float64))

    def __call__(self, result):
        return jnp.mean((result.trajectory.x[:, 0] - self.observed) ** 2) / MISFIT_SCALE**2


def identify(
    ts: Float[ArrayLike, " J"],
    observed: Float[ArrayLike, " J"],
    bounds: dict,
    *,
    base: Params | None = None,
    numerics: Numerics = PRESETS["default"],
    starts=3,
    steps: int = 30,
    optimiser=None,
    seed: int = 0,
    path=None,
    progress: bool = True,
    box: str = "sigmoid",
    overwrite: bool = False,
    crack_sensitivity: str | None = None,
) -> OptimiseResult:
    """Least-squares fit of the parameters in `bounds` to the head positions `observed`
    [m] at the times `ts` [s] (t1 = ts[-1]); the other parameters are `base`'s. Returns the
    `OptimiseResult` (objective: `head_misfit`, minimised).

    `box` defaults to the sigmoid, not `optimise`'s sine: the soil's parameters lie
    inside their bounds, so every evaluated point stays strictly inside, and the default
    optimiser is Adam with momentum (`DEFAULT_OPTIMISERS["sigmoid"]`).

    `crack_sensitivity` is `optimise`'s. The default numerics (Kvaerno3) differentiate
    K_Ic and K_Ith with each new tip held; with Rodas4 (`fast`), whose default holds the
    crack schedule these act through, they need `"exact"` (refused otherwise)."""
    ts = np.asarray(ts, dtype=np.float64)
    observed = np.asarray(observed, dtype=np.float64)
    if ts.shape != observed.shape or ts.ndim != 1 or ts.size == 0:
        raise ValueError(
            f"ts (shape {ts.shape}) and observed (shape {observed.shape}): need "
            "two 1-D arrays of one length"
        )
    if not (np.all(np.isfinite(ts)) and np.all(np.diff(ts) > 0) and ts[0] >= 0 and ts[-1] > 0):
        raise ValueError("option ts: need finite, increasing times >= 0 [s], the last > 0")
    bad = np.flatnonzero(~np.isfinite(observed))
    if bad.size:
        raise ValueError(
            f"option observed: {bad.size} value(s) not finite (the first at index "
            f"{bad[0]}, t = {ts[bad[0]]:g} s): need finite head positions [m]"
        )
    return optimise(
        head_misfit(observed),
        bounds,
        base=base,
        t1=float(ts[-1]),
        numerics=numerics,
        starts=starts,
        steps=steps,
        optimiser=optimiser,
        seed=seed,
        path=path,
        progress=progress,
        ts=jnp.asarray(ts),
        box=box,
        overwrite=overwrite,
        crack_sensitivity=crack_sensitivity,
    )
