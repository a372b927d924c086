"""The step loop of a sweep's chunks (`jaxworm._steps`): one loop of steps per run, its
crack events inside it, against the scan of crack segments that `simulate` runs.

A lone run takes the same steps, events and jumps in both loops, so every field agrees
bit for bit: the cracks (located, jumped, recorded, the next segment started afresh),
the crack bound, the step bound, a collapse (also one at t = 0), a crack at t = 0, soil
that varies and a controller that reads the crack. In a batch the lanes' rounding
differs from a lone run's (as for any vmapped solve), so there the check is each lane's
own run. Scenes of one parameter structure and one set of static options share their
programs (t1 is an input of them).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw
from jaxworm._solve import simulate_steps

FAST = jw.PRESETS["fast"]

SCENES = {
    "cracks": (jw.Params().replace(delta=-math.pi / 4), 8.0, FAST),
    "crack bound": (
        jw.Params().replace(delta=-math.pi / 6, K_Ith=235.0),
        4.0,
        FAST.replace(max_cracks=2),
    ),
    "step bound": (jw.Params(), 4.0, FAST.replace(max_steps=50)),
    "collapse": (jw.Params().replace(A=0.05, omega=2 * math.pi), 8.0, FAST),
    # Intrinsic lengths below zero at t = 0: collapsed before the first step.
    "collapsed at t = 0": (
        jw.Params(gait=jw.TravellingWave(A=0.1, omega=2 * math.pi, delta=0.0, offset="centred")),
        8.0,
        FAST,
    ),
    "crack at t = 0": (
        jw.Params().replace(delta=-math.pi / 6, K_Ith=235.0, crack_gap0=1e-3),
        1.0,
        FAST,
    ),
    "layered soil": (
        jw.Params().replace(delta=-math.pi / 4, K_Ic=jw.Layered([0.17], [250.0, 300.0])),
        8.0,
        FAST,
    ),
    "other options": (
        jw.Params().replace(delta=-math.pi / 6, K_Ith=235.0, crack_gap0=1e-3),
        1.0,
        FAST.replace(interpolant="hermite", dt_max=0.005, linear_solve="dense", pcoeff=0.0),
    ),
    "reflex": (
        jw.Params(
            gait=jw.ReflexWave(A=0.02, omega=4 * math.pi, delta=-math.pi / 4, gain_stress=50.0)
        ),
        2.0,
        FAST.replace(crack_sensitivity="exact"),
    ),
}


@pytest.mark.parametrize("scene", list(SCENES))
def test_a_lone_run_is_the_scan_of_segments_bit_for_bit(scene):
    p, t1, numerics = SCENES[scene]
    a = jw.simulate(p, t1, numerics)
    b = simulate_steps(p, t1, numerics)
    expected = {
        "cracks": "ok",
        "crack bound": "too_many_cracks",
        "step bound": "max_steps_reached",
        "collapse": "body_inverted",
        "collapsed at t = 0": "body_inverted",
        "crack at t = 0": "ok",
        "layered soil": "ok",
        "reflex": "ok",
        "other options": "ok",
    }[scene]
    assert a.status_name == expected
    if scene in ("cracks", "layered soil", "reflex", "crack bound", "other options"):
        assert int(a.n_cracks) >= 2
    if scene == "crack at t = 0":
        assert float(a.crack_times[0]) == 0.0
    if scene == "collapsed at t = 0":
        assert int(a.steps) == 0 and float(a.t_end) == 0.0
    leaves_a = jax.tree_util.tree_leaves_with_path(a)
    leaves_b = jax.tree_util.tree_leaves_with_path(b)
    assert [k for k, _ in leaves_a] == [k for k, _ in leaves_b]
    for (path, x), (_, y) in zip(leaves_a, leaves_b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=str(path))


def test_each_lane_of_a_batch_is_its_own_run():
    # Lanes that crack at other times and rates (and one that never cracks, one that
    # stops at the crack bound) in one batch: each ends as it does alone, to the
    # solver's tolerance (a batch rounds differently from a lone run).
    deltas = jnp.array([-math.pi / 4, -math.pi / 6, math.pi / 4, -math.pi / 3])
    omegas = jnp.array([4 * math.pi, 3 * math.pi, 4 * math.pi, 5 * math.pi])
    numerics = FAST.replace(max_cracks=2)

    def one(d, w):
        return simulate_steps(jw.Params().replace(delta=d, omega=w), 8.0, numerics)

    batch = jax.jit(jax.vmap(one))(deltas, omegas)
    for i in range(deltas.size):
        alone = jw.simulate(jw.Params().replace(delta=deltas[i], omega=omegas[i]), 8.0, numerics)
        assert int(batch.status[i]) == int(alone.status), i
        assert int(batch.n_cracks[i]) == int(alone.n_cracks), i
        assert float(batch.mean_velocity[i]) == pytest.approx(
            float(alone.mean_velocity), rel=2e-3
        ), i
    names = list(jw.status_name(batch.status))
    assert "too_many_cracks" in names and "ok" in names
    assert int(jnp.min(batch.n_cracks)) == 0 and int(jnp.max(batch.n_cracks)) == 2


def test_its_derivative_is_refused_not_taken_through_the_steps():
    p = jw.Params().replace(delta=-math.pi / 4)

    def v(a):
        return simulate_steps(p.replace(A=a), 1.0).mean_velocity

    with pytest.raises(TypeError, match="forward only.*differentiate jaxworm.simulate"):
        jax.jvp(v, (0.02,), (1.0,))
    with pytest.raises(TypeError, match="forward only"):
        jax.grad(v)(0.02)
    with pytest.raises(TypeError, match="forward only"):
        jax.grad(lambda t1: simulate_steps(p, t1).mean_velocity)(1.0)
