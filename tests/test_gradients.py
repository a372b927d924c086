"""Gradients through the solve and its crack events, against central finite differences.

The reference is a tightly solved model: the default solver (Rodas4) with positions
bounded to 1e-12 m per step. Its mean velocity jitters by ~1e-6 m/s as adaptive steps
shift with the parameters, so finite differences of the mean velocity in the gait
(A, ω, δ) use a 1 % parameter step, large enough that this noise floor stays far below
the 2 % budget (and checked against a 0.5 % step).

The crack events need smaller steps: the crack times and tips are piecewise smooth in
the parameters. A change of K_Ic or K_Ith by ~1e-3, or of A by 1 %, moves an earlier
crack onto another peak of the oscillating K_I (on `wave_retro`, +1 % in A moves the
third crack 0.2 s later), and a difference that straddles such a jump is off by orders
of magnitude. So the events' differences use 0.3 % in A and ω (checked against 0.1 %)
and 1e-4 in K_Ic and K_Ith (checked against 3e-5), and each test first asserts that the
step and its check agree to 1 % (a straddled jump differs by 100 % or more). At atol
1e-11 the reference's own jitter came close to that: the third crack's tip on
`slow_steep` differenced in ω at 0.3, 0.2, 0.1 and 0.05 % spread over 2.4 %, and a
rounding-level change of the vector field moved the 0.3 % and 0.1 % differences 1.2 %
apart; at 1e-12 the four agree within 0.2 %. Much smaller steps in A and ω meet the
event times' own jitter instead (at atol 1e-10, 1e-4 and 3e-5 in A gave third-crack
times 7 % apart).

Objectives: the mean velocity with respect to the gait (A, ω, δ) (barely affected by the
crack tip, which enters only through the back pressure, ~1e-7 N against ~1e-4 N of
friction), and the time and new tip of the third crack with respect to (A, ω, K_Ic,
K_Ith), set by the event location (eq. 12) and the state there (eq. 13) after two
earlier jumps: these test the event sensitivities themselves. (The final tip x_c(t1) is
no good for finite differences: a 1 % change of K_Ith changes how many cracks fit before
t1, and x_c(t1) jumps with it.)

Derivatives checked: the default solver's exact forward sensitivities, and diffrax's
forward-mode AD through Kvaerno5 (`adjoint="forward"`). diffrax's derivative carries
the solver's error, which converges slowly with the tolerance: at atol 1e-10 its
third-crack tip on `slow_steep` was 2.0 % off the differences, at 1e-11 0.4 %
(docs/known-issues.md), so it is checked at 1e-11. Its reverse mode is checked too, on the
scene where that error is largest.

The mean velocity's sensitivities to the soil's E_s and μ_s are not asserted: friction
and normal force scale together with them, so the speed barely moves (d v̄/dE_s ~ 5e-10
to 1e-8 m/s per Pa). Measured with relative steps 1e-2 ... 1e-4: on the first scene
d v̄/dμ_s agrees with AD to 0.4 % at 1e-2 (E_s: 4–9 %, the differences drifting with the
step), while on the other two the differences swing by factors of 2 to 20 between
steps: below the noise floor of the tight solve.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw

#: The finite differences' model, tightly solved.
REFERENCE = jw.PRESETS["fast"].replace(atol=1e-12, max_cracks=8)
#: diffrax's AD through the events, with the exact jump conditions.
DIFFRAX = jw.Numerics(
    solver="Kvaerno5", atol=1e-11, max_cracks=8, crack_sensitivity="exact", adjoint="forward"
)
#: The default solver with the exact jump conditions at the events, its sensitivities
#: solved to tolerance (at the default sensitivity_tol, over 2.5 s, the step sequence's
#: jitter moves d v̄/dδ by ~2 %: docs/known-issues.md).
SENSITIVITIES = jw.PRESETS["fast"].replace(
    max_cracks=8, crack_sensitivity="exact", sensitivity_tol=1.0
)
T1 = 2.5
SCENES = {
    "wave_retro": dict(delta=-jnp.pi / 6, K_Ith=235.0),
    "slow_steep": dict(omega=3 * jnp.pi, delta=-jnp.pi / 3, K_Ith=235.0),
    "other_soil": dict(E_s=1.6e5, K_Ic=260.0, K_Ith=245.0, delta=-jnp.pi / 4, omega=5 * jnp.pi),
}
NAMES = ("A", "omega", "delta", "K_Ic", "K_Ith")
#: Relative central-difference steps (the step, and its check) for the mean velocity
#: (objective 0) and for the third crack's time and tip (objectives 1 and 2).
VELOCITY_STEPS = {"A": (1e-2, 5e-3), "omega": (1e-2, 5e-3), "delta": (1e-2, 5e-3)}
EVENT_STEPS = {
    "A": (3e-3, 1e-3),
    "omega": (3e-3, 1e-3),
    "K_Ic": (1e-4, 3e-5),
    "K_Ith": (1e-4, 3e-5),
}
DIFFERENCES = [("velocity", n, VELOCITY_STEPS[n]) for n in VELOCITY_STEPS] + [
    ("event", n, EVENT_STEPS[n]) for n in EVENT_STEPS
]
BASE = jw.Params()


def _objectives(vals, numerics):
    r = jw.simulate(BASE.replace(**vals), T1, numerics)
    return jnp.stack([r.mean_velocity, r.crack_times[2], r.crack_tips[2]]), r.n_cracks


def _point(scene):
    p = BASE.replace(**scene)
    return {n: jnp.asarray(p.flat()[n], dtype=jnp.float64) for n in NAMES}


def _fd_lanes(points, which):
    """The parameter values of the central differences (`which`: 0 the step, 1 the
    check): for each point and each difference, + then − its relative step, the other
    parameters fixed."""
    lanes = {n: [] for n in NAMES}
    for pt in points:
        for _, name, steps in DIFFERENCES:
            for sign in (1.0, -1.0):
                for m in NAMES:
                    x = float(pt[m])
                    lanes[m].append(x + sign * steps[which] * abs(x) if m == name else x)
    return {n: jnp.array(v) for n, v in lanes.items()}


@pytest.fixture(scope="module")
def gradients():
    """Derivatives of the objectives at the scenes of each mode, batched across them
    through the crack events (diffrax's forward mode by jacfwd, the default solver's
    sensitivities by jacrev; diffrax's reverse mode in a batch of its one scene), with
    the crack counts of those runs, and the central differences. The two difference
    batches (the step and its check) have one shape: one compiled program."""
    points = [_point(s) for s in SCENES.values()]
    forward = eqx.filter_jit(jax.vmap(lambda v: _objectives(v, REFERENCE)))

    def differences(which):
        vals, cracks = forward(_fd_lanes(points, which))
        vals = np.asarray(vals).reshape(len(points), len(DIFFERENCES), 2, 3)
        steps = np.array(
            [[s[which] * abs(float(pt[n])) for _, n, s in DIFFERENCES] for pt in points]
        )
        fd = (vals[:, :, 0, :] - vals[:, :, 1, :]) / (2 * steps[:, :, None])
        return fd, np.asarray(cracks)

    fd = {}
    for which in (0, 1):  # the step, then the check
        fd[which], fd[f"cracks{which}"] = differences(which)

    def derivative(numerics, jac, scenes):
        """vmap of `jac` across `scenes`, through the events, and each lane's crack count."""
        f = jac(lambda v: _objectives(v, numerics), has_aux=True)
        batch = {n: jnp.stack([_point(SCENES[s])[n] for s in scenes]) for n in NAMES}
        d, cracks = eqx.filter_jit(jax.vmap(f))(batch)
        return d, np.asarray(cracks)

    how = {
        "diffrax": (DIFFRAX, jax.jacfwd),
        # jacrev: the transpose of the same forward sensitivities (the reverse path).
        "sensitivity": (SENSITIVITIES, jax.jacrev),
        "diffrax_reverse": (DIFFRAX.replace(adjoint="reverse"), jax.jacrev),
    }
    out = {mode: derivative(num, jac, MODES[mode]) for mode, (num, jac) in how.items()}
    return {
        **{mode: d for mode, (d, _) in out.items()},
        "fd": fd,
        "cracks": {mode: c for mode, (_, c) in out.items()},
    }


def test_every_gradient_scene_has_at_least_three_crack_events(gradients):
    for mode, cracks in gradients["cracks"].items():  # the derivatives' own runs
        assert np.all(cracks >= 3), (mode, cracks)
    assert np.all(gradients["fd"]["cracks0"] >= 3)  # the third crack exists in every lane
    assert np.all(gradients["fd"]["cracks1"] >= 3)


#: The derivatives checked, and the scenes each is checked on. diffrax's reverse mode
#: (recursive checkpointing) runs on the scene where its error is largest, alone: over
#: three lanes its run took as long as the other checks together.
MODES = {
    "diffrax": list(SCENES),
    "sensitivity": list(SCENES),
    "diffrax_reverse": ["slow_steep"],
}


def _richardson(steps, fd, fd_check):
    """The central differences at steps h and h/r extrapolated to h → 0: their error
    is c h² + O(h⁴), so D ≈ fd_check + (fd_check − fd)/(r² − 1). Over a fixed t1 the
    mean velocity curves in ω within each gait period (the sawtooth of
    docs/gradients.md), and the 1 % difference carries that curvature: on the
    `slow_steep` scene the differences at 1 % and 0.5 % step 2 % apart, and the
    derivative sits beyond both, where the extrapolation puts it."""
    r = steps[0] / steps[1]
    return fd_check + (fd_check - fd) / (r**2 - 1)


def _differences(gradients, mode, kind, name, objective):
    """The step's and the check's differences on the scenes of `mode`."""
    d = [i for i, (k, n, _) in enumerate(DIFFERENCES) if (k, n) == (kind, name)][0]
    rows = [list(SCENES).index(scene) for scene in MODES[mode]]
    return gradients["fd"][0][rows, d, objective], gradients["fd"][1][rows, d, objective]


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", ["A", "omega", "delta"])
def test_mean_velocity_gradient_matches_finite_differences(gradients, name, mode):
    if name == "omega" and mode.startswith("sensitivity"):
        pytest.skip(
            "over a fixed t1, d v̄/dω carries the mean node velocity at t1 (the "
            "gait's phase there), which the default solve does not control: "
            "checked over whole periods in test_sensitivity.py"
        )
    ad = np.asarray(gradients[mode][name])[:, 0]
    fd, fd_half = _differences(gradients, mode, "velocity", name, 0)
    ref = _richardson(VELOCITY_STEPS[name], fd, fd_half)
    noise = np.abs(fd - fd_half)  # the finite differences' own disagreement
    err = np.abs(ad - ref)
    assert np.all(err <= np.maximum(0.02 * np.abs(ref), 2 * noise)), (ad, ref, fd, fd_half)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("which", [1, 2], ids=["crack_time", "crack_tip"])
@pytest.mark.parametrize("name", ["A", "omega", "K_Ic", "K_Ith"])
def test_third_crack_gradient_through_events_matches_finite_differences(
    gradients, name, which, mode
):
    ad = np.asarray(gradients[mode][name])[:, which]
    fd, fd_check = _differences(gradients, mode, "event", name, which)
    # The two steps agree: neither straddles a jump of the crack schedule.
    assert np.all(np.abs(fd - fd_check) <= 0.01 * np.abs(fd)), (fd, fd_check)
    assert np.all(np.abs(ad - fd) <= 0.02 * np.abs(fd)), (ad, fd, fd_check)
    assert np.all(np.abs(fd) > 0)


@pytest.mark.parametrize(
    "preset, atol, rtol",
    [
        # The default solver's sensitivities take ∂y(t1)/∂t1 = f(y(t1)): exact.
        ("fast", None, 1e-12),
        # diffrax differentiates its last step's length instead: f to that step's local
        # error, which depends on where t1 falls. At atol 1e-10 the identity held to
        # 7e-9 at this t1 and to 5.1e-5 at worst over t1 = 0.5 ... 0.8 (at 1e-8: 1.6e-5
        # here, 3.5e-4 at t1 = 0.62).
        ("default", 1e-10, 1e-4),
    ],
)
def test_derivative_with_respect_to_the_horizon_is_the_velocity_identity(preset, atol, rtol):
    # v̄(t1) = (x̄(t1) − x̄(0))/t1, so dv̄/dt1 = (mean node velocity at t1 − v̄)/t1 exactly:
    # the path `horizon="whole_periods"` differentiates through (t1 = K·2π/ω).
    num = jw.PRESETS[preset].replace(adjoint="forward", crack_sensitivity="exact")
    if atol is not None:
        num = num.replace(atol=atol)
    p = BASE.replace(delta=-jnp.pi / 4)
    t1 = 0.61

    # The identity's right side from the same solve as the derivative: on the
    # sensitivities' path the derivative's steps are controlled on the sensitivities
    # too, so a separate forward solve takes other steps.
    def velocity(t):
        r = jw.simulate(p, t, num)
        return r.mean_velocity, (jnp.mean(r.final.v), r.mean_velocity)

    dv, (v_end, v_mean) = jax.jacfwd(velocity, has_aux=True)(t1)
    expected = (float(v_end) - float(v_mean)) / t1
    np.testing.assert_allclose(float(dv), expected, rtol=rtol)
    assert abs(expected) > 1e-3  # mid-stroke: the head is not at its mean speed


def test_reverse_mode_under_vmap_with_lanes_that_finish_early():
    # diffrax's reverse mode (what `train` takes for many parameters) over a batch whose
    # lanes crack once and 4 times: the finished lane runs (and discards) the segments
    # the other still needs. Each lane's gradient is finite and is its lone solve's.
    # Room for 8 cracks (the lanes crack 1 and 4 times): fewer segments to scan.
    numerics = jw.Numerics(solver="Kvaerno3", atol=1e-10, crack_sensitivity="exact", max_cracks=8)

    def v(A, delta):
        gait = jw.TravellingWave(A=A, omega=9.5, delta=delta)
        r = jw.simulate(jw.Params(gait=gait), 2.0, numerics)
        return r.mean_velocity, r.n_cracks

    batch = jax.jit(jax.vmap(jax.grad(v, has_aux=True), in_axes=(None, 0)))
    deltas = jnp.array([-0.8, -0.2])
    batched, cracks = batch(0.03, deltas)
    assert cracks[0] < cracks[1] and cracks[1] >= 3
    assert np.all(np.isfinite(np.asarray(batched)))
    for i in range(2):
        # A lane alone: both lanes the same gait, so neither finishes early (and the
        # batch's compiled program serves).
        one, n = (a[0] for a in batch(0.03, jnp.full(2, deltas[i])))
        assert n == cracks[i]
        # diffrax couples a batch's lanes at rounding level (its FSAL stage is evaluated
        # afresh when any lane starts or jumps), which moves adaptive steps: the lanes
        # agree with lone solves within the derivative's own error, not bit for bit.
        np.testing.assert_allclose(float(batched[i]), float(one), rtol=2e-2)
