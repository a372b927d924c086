"""Gradients through the solve and its crack events, against central finite differences.

The reference is a tightly solved model (Kvaerno5, positions bounded to 1e-10 m per
step). Its mean velocity jitters by ~1e-6 m/s as adaptive steps shift with the
parameters, so finite differences use a 1 % parameter step, large enough that this
noise floor stays far below the 2 % budget (and checked against a 0.5 % step).

Objectives: the mean velocity (barely affected by the crack tip, which enters only
through the back pressure, ~1e-7 N against ~1e-4 N of friction), and the time and new
tip of the third crack, set by the event location (eq. 12) and the state there
(eq. 13) after two earlier jumps: these test the event sensitivities themselves. (The
final tip x_c(t1) is no good for finite differences: a 1 % change of K_Ith changes how
many cracks fit before t1, and x_c(t1) jumps with it.)
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw

TIGHT = jw.Numerics(solver="Kvaerno5", atol=1e-10, max_cracks=8)
T1 = 2.5
SCENES = {
    "wave_retro": dict(delta=-jnp.pi / 6, K_Ith=235.0),
    "slow_steep": dict(omega=3 * jnp.pi, delta=-jnp.pi / 3, K_Ith=235.0),
    "other_soil": dict(E_s=1.6e5, K_Ic=260.0, K_Ith=245.0, delta=-jnp.pi / 4, omega=5 * jnp.pi),
}
NAMES = ("A", "omega", "delta", "K_Ic", "K_Ith")
BASE = jw.Params()


def _objectives(vals, numerics=TIGHT):
    r = jw.simulate(BASE.replace(**vals), T1, numerics)
    return jnp.stack([r.mean_velocity, r.crack_times[2], r.crack_tips[2]]), r.n_cracks


def _point(scene):
    p = BASE.replace(**scene)
    return {n: jnp.asarray(p.flat()[n], dtype=jnp.float64) for n in NAMES}


@pytest.fixture(scope="module")
def gradients():
    points = [_point(s) for s in SCENES.values()]
    stacked = {n: jnp.stack([pt[n] for pt in points]) for n in NAMES}
    # vmap of reverse mode through the Kvaerno solvers fails through crack events (a
    # non-finite linear solve inside diffrax's event root find; see the README's known
    # issues), so the reverse-mode Jacobians run one after another with lax.map.
    jac = eqx.filter_jit(lambda s: jax.lax.map(jax.jacrev(lambda v: _objectives(v)[0]), s))(stacked)
    # Forward mode (diffrax.ForwardMode) does batch: vmap of jacfwd across the scenes.
    forward_mode = TIGHT.replace(adjoint="forward")
    jac_fwd = eqx.filter_jit(jax.vmap(jax.jacfwd(lambda v: _objectives(v, forward_mode)[0])))(stacked)
    forward = eqx.filter_jit(jax.vmap(_objectives))
    fd = {}
    for rel in (1e-2, 5e-3):
        lanes = {n: [] for n in NAMES}
        for pt in points:
            for n in NAMES:
                for sign in (1.0, -1.0):
                    for m in NAMES:
                        x = float(pt[m])
                        lanes[m].append(x + sign * rel * abs(x) if m == n else x)
        (vals, cracks) = forward({n: jnp.array(v) for n, v in lanes.items()})
        vals = np.asarray(vals).reshape(len(points), len(NAMES), 2, 3)
        steps = np.array([[rel * abs(float(pt[n])) for n in NAMES] for pt in points])
        fd[rel] = (vals[:, :, 0, :] - vals[:, :, 1, :]) / (2 * steps[:, :, None])
        fd[f"cracks{rel}"] = np.asarray(cracks).reshape(len(points), len(NAMES), 2)
    base_vals, base_cracks = forward(stacked)
    return {"jac": jac, "jac_fwd": jac_fwd, "fd": fd, "cracks": np.asarray(base_cracks)}


def test_every_gradient_scene_has_at_least_three_crack_events(gradients):
    assert np.all(gradients["cracks"] >= 3)
    assert np.all(gradients["fd"]["cracks0.01"] >= 3)  # the third crack exists in every lane


@pytest.mark.parametrize("mode", ["reverse_lax_map", "forward_vmap"])
@pytest.mark.parametrize("name", ["A", "omega", "delta"])
def test_mean_velocity_gradient_matches_finite_differences(gradients, name, mode):
    i = NAMES.index(name)
    ad = np.asarray(gradients["jac" if mode == "reverse_lax_map" else "jac_fwd"][name])[:, 0]
    fd, fd_half = gradients["fd"][1e-2][:, i, 0], gradients["fd"][5e-3][:, i, 0]
    noise = np.abs(fd - fd_half)  # the finite differences' own disagreement
    err = np.abs(ad - fd)
    assert np.all(err <= np.maximum(0.02 * np.abs(fd), 2 * noise)), (ad, fd, fd_half)


# Known defect, kept visible: the new tip's sensitivity to the fracture constants
# (through the head's state at the event, eq. 13) disagrees with the finite differences
# (AD 2.1e-3 against FD 9.8e-4 / 4.4e-4 m per Pa√m at 1 % / 0.5 % steps on the first
# scene), while the crack times' sensitivities to the same constants agree. Strict, so
# a fix shows up as a failure to remove this mark.
_TIP_VS_FRACTURE = pytest.mark.xfail(
    strict=True, reason="crack-tip sensitivity to K_Ic/K_Ith disagrees with FD (open)")


@pytest.mark.parametrize("mode", ["reverse_lax_map", "forward_vmap"])
@pytest.mark.parametrize("which", [1, 2], ids=["crack_time", "crack_tip"])
@pytest.mark.parametrize("name", ["A", "omega", "K_Ic", "K_Ith"])
def test_third_crack_gradient_through_events_matches_finite_differences(
        gradients, name, which, mode, request):
    if which == 2 and name in ("K_Ic", "K_Ith"):
        request.applymarker(_TIP_VS_FRACTURE)
    i = NAMES.index(name)
    ad = np.asarray(gradients["jac" if mode == "reverse_lax_map" else "jac_fwd"][name])[:, which]
    fd, fd_half = gradients["fd"][1e-2][:, i, which], gradients["fd"][5e-3][:, i, which]
    noise = np.abs(fd - fd_half)
    err = np.abs(ad - fd)
    assert np.all(err <= np.maximum(0.02 * np.abs(fd), 2 * noise)), (ad, fd, fd_half)
    assert np.all(np.abs(fd) > 0)

