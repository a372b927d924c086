"""Parameters: Table 1 defaults, construction-time validation, traced validation."""

import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw

# Table 1 of the paper (SI units)
TABLE1 = {
    "E_s": 1.4e5,
    "K_Ic": 250.0,
    "K_Ith": 200.0,
    "nu": 0.3,
    "w_c": 1e-3,
    "Wg": 4.59e-4,
    "EA": 13.0,
    "w0": 1e-3,
    "l0": 1e-2,
    "h": 1e-3,
    "m": 1e-5,
    "mu_s": 0.3,
    "lam": 1.5,
    "A": 0.02,
    "omega": 4 * math.pi,
    "delta": math.pi / 4,
}

# every float parameter a user can set by its flat name
FLOAT_NAMES = sorted(set(jw.FLAT_NAMES) - {"N"})


# --- defaults -----------------------------------------------------------------------


def test_defaults_equal_table1():
    p = jw.Params()
    assert p.body.N == 7
    flat = p.flat()
    for name, value in TABLE1.items():
        assert flat[name].dtype == jnp.float64, name
        assert float(flat[name]) == pytest.approx(value, rel=1e-15), name


def test_default_conventions_from_model_md():
    p = jw.Params()
    assert float(p.smoothing.eps_v) == 1e-4  # tanh(v / 1e-4 m/s)
    assert p.smoothing.exact is False
    assert p.crack_gap0 is None  # tip from eq. 13 at t = 0
    assert p.soil.wedge == "given"
    assert isinstance(p.gait, jw.TravellingWave) and p.gait.offset == "rest"
    assert float(p.wedge_number) == 4.59e-4


def test_flat_names_cover_flat():
    assert set(jw.Params().flat()) == set(jw.FLAT_NAMES)


# --- parameter facts: one table, the others derived ---------------------------------


def test_flat_names_derive_from_the_parameter_table_grouped_by_field():
    from jaxworm._params import PARAMETER_INFO

    assert list(jw.FLAT_NAMES.items()) == [
        ("N", "body"),
        ("EA", "body"),
        ("w0", "body"),
        ("l0", "body"),
        ("h", "body"),
        ("m", "body"),
        ("lam", "body"),
        ("E_s", "soil"),
        ("K_Ic", "soil"),
        ("K_Ith", "soil"),
        ("nu", "soil"),
        ("w_c", "soil"),
        ("Wg", "soil"),
        ("mu_s", "soil"),
        ("A", "gait"),
        ("omega", "gait"),
        ("delta", "gait"),
        ("eps_v", "smoothing"),
        ("eps_N", "smoothing"),
        ("crack_gap0", None),
    ]
    assert {n: i.group for n, i in PARAMETER_INFO.items()} == jw.FLAT_NAMES


def test_sweep_file_units_derive_from_the_parameter_table_in_ascii():
    from jaxworm import _sweep

    assert _sweep.UNITS == {
        "N": "-",
        "E_s": "Pa",
        "K_Ic": "Pa m^0.5",
        "K_Ith": "Pa m^0.5",
        "nu": "-",
        "w_c": "m",
        "Wg": "-",
        "EA": "N",
        "w0": "m",
        "l0": "m",
        "h": "m",
        "m": "kg",
        "mu_s": "-",
        "lam": "-",
        "A": "m/s",
        "omega": "rad/s",
        "delta": "rad",
        "eps_v": "m/s",
        "eps_N": "N",
        "crack_gap0": "m",
    }
    assert all(u.isascii() for u in _sweep.UNITS.values())


# --- construction-time validation ---------------------------------------------------


def _raises_naming(name, shown, allowed, **values):
    with pytest.raises(ValueError) as info:
        jw.Params().replace(**values)
    msg = str(info.value)
    assert re.search(rf"\b{re.escape(name)} = {re.escape(shown)}", msg), msg
    assert allowed in msg, msg
    return msg


BAD_RANGES = [
    # (name, bad value, text of the allowed range)
    ("EA", 0.0, "> 0"),
    ("EA", -13.0, "> 0"),
    ("w0", 0.0, "> 0"),
    ("w0", -1e-3, "> 0"),
    ("l0", 0.0, "> 0"),
    ("l0", -0.01, "> 0"),
    ("h", 0.0, "> 0"),
    ("h", -1e-3, "> 0"),
    ("m", 0.0, "> 0"),
    ("m", -1e-5, "> 0"),
    ("E_s", 0.0, "> 0"),
    ("E_s", -1.4e5, "> 0"),
    ("w_c", 0.0, "> 0"),
    ("w_c", -1e-3, "> 0"),
    ("Wg", 0.0, "> 0"),
    ("Wg", -4.59e-4, "> 0"),
    ("K_Ic", 0.0, "> 0"),
    ("K_Ic", -250.0, "> 0"),
    ("K_Ith", 0.0, "> 0"),
    ("K_Ith", -200.0, "> 0"),
    ("omega", 0.0, "> 0"),
    ("omega", -1.0, "> 0"),
    ("nu", -0.1, "[0, 0.5)"),
    ("nu", 0.5, "[0, 0.5)"),
    ("nu", 0.7, "[0, 0.5)"),
    ("lam", 0.99, ">= 1"),
    ("lam", 0.0, ">= 1"),
    ("lam", -1.5, ">= 1"),
    ("mu_s", -0.1, ">= 0"),
    ("eps_v", 0.0, "> 0"),
    ("eps_v", -1e-4, "> 0"),
    ("eps_N", 0.0, "> 0"),
    ("eps_N", -1e-8, "> 0"),
    ("crack_gap0", 0.0, "> 0"),
    ("crack_gap0", -0.05, "> 0"),
]


@pytest.mark.parametrize("name,value,allowed", BAD_RANGES)
def test_out_of_range_raises_naming_parameter_value_and_range(name, value, allowed):
    _raises_naming(name, repr(float(value)), allowed, **{name: value})


@pytest.mark.parametrize("value", [250.0, 300.0])
def test_K_Ith_must_stay_below_K_Ic(value):
    msg = _raises_naming("K_Ith", repr(value), "K_Ic", K_Ith=value)
    assert "250.0" in msg  # the bound it violated


def test_lowering_K_Ic_below_K_Ith_is_reported_with_both_values():
    with pytest.raises(ValueError) as info:
        jw.Params().replace(K_Ic=150.0)
    msg = str(info.value)
    assert "K_Ith" in msg and "K_Ic = 150.0" in msg and "200.0" in msg, msg


@pytest.mark.parametrize("name", FLOAT_NAMES)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_every_value_must_be_finite(name, bad):
    _raises_naming(name, repr(bad), name, **{name: bad})


@pytest.mark.parametrize("N", [1, 0, -3])
def test_N_at_least_two(N):
    with pytest.raises(ValueError, match=rf"\bN = {N}\b.*N >= 2"):
        jw.Body(N=N)
    with pytest.raises(ValueError, match=rf"\bN = {N}\b"):
        jw.Params().replace(N=N)


def test_N_must_be_an_integer():
    with pytest.raises(ValueError, match=r"\bN = 2\.5\b"):
        jw.Body(N=2.5)


def test_static_integers_take_numpy_and_0d_integer_arrays_as_python_ints():
    """A NumPy integer was stored as it came: equinox warned of an array set as static,
    and a scene of N = np.int64(5) was another compiled program than N = 5."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        body = jw.Params().replace(N=np.int64(5)).body
        numerics = jw.Numerics(max_cracks=np.int64(3), max_steps=jnp.array(100))
    assert type(body.N) is int and body == jw.Body(N=5) and jw.Body(N=jnp.array(5)).N == 5
    assert numerics == jw.Numerics(max_cracks=3, max_steps=100)
    assert type(numerics.max_cracks) is int and type(numerics.max_steps) is int


def test_direct_constructors_validate():
    with pytest.raises(ValueError, match=r"nu = 0\.5\b.*\[0, 0\.5\)"):
        jw.Soil(nu=0.5)
    with pytest.raises(ValueError, match=r"omega = -1\.0\b.*> 0"):
        jw.TravellingWave(omega=-1.0)
    with pytest.raises(ValueError, match=r"eps_v = 0\.0\b.*> 0"):
        jw.Smoothing(eps_v=0.0)
    with pytest.raises(ValueError, match=r"lam = 0\.5\b.*>= 1"):
        jw.Body(lam=0.5)
    with pytest.raises(ValueError, match=r"offset"):
        jw.TravellingWave(offset="middle")
    with pytest.raises(ValueError, match=r"wedge"):
        jw.Soil(wedge="eq6")


@pytest.mark.parametrize(
    "values",
    [
        dict(N=2),
        dict(nu=0.0),
        dict(nu=0.4999),
        dict(lam=1.0),
        dict(mu_s=0.0),
        dict(K_Ith=249.999),
        dict(A=0.0),
        dict(A=-0.02),
        dict(delta=-1.0),
        dict(delta=0.0),
        dict(crack_gap0=0.05),
    ],
)
def test_boundary_values_are_accepted(values):
    p = jw.Params().replace(**values)
    for name, value in values.items():
        got = p.body.N if name == "N" else p.flat()[name]
        assert float(got) == value
    assert bool(jw.params_valid(p))


def test_replace_unknown_name_raises_naming_it():
    with pytest.raises(ValueError, match=r"unknown parameter 'omgea'"):
        jw.Params().replace(omgea=3.0)


def test_replace_returns_a_validated_copy():
    p = jw.Params()
    q = p.replace(omega=3 * math.pi, E_s=2e5, N=4)
    assert float(q.gait.omega) == pytest.approx(3 * math.pi, rel=1e-15)
    assert float(q.soil.E_s) == 2e5 and q.body.N == 4
    assert q.body.node_masses.shape == (4,)
    # the original is untouched
    assert float(p.gait.omega) == pytest.approx(4 * math.pi, rel=1e-15) and p.body.N == 7


# --- traced validation ----------------------------------------------------------------


def test_params_valid_concrete():
    assert bool(jw.params_valid(jw.Params()))


def test_params_valid_traced_omega():
    ok = jax.vmap(lambda w: jw.params_valid(jw.Params().replace(omega=w)))(jnp.array([1.0, -1.0]))
    np.testing.assert_array_equal(np.asarray(ok), [True, False])


@pytest.mark.parametrize(
    "name,good,bad",
    [
        ("EA", 13.0, -1.0),
        ("w0", 1e-3, 0.0),
        ("l0", 1e-2, -1e-2),
        ("h", 1e-3, 0.0),
        ("m", 1e-5, -1e-5),
        ("E_s", 1.4e5, 0.0),
        ("E_s", 1.4e5, math.nan),
        ("nu", 0.3, 0.5),
        ("nu", 0.3, -0.01),
        ("lam", 1.5, 0.9),
        ("mu_s", 0.3, -0.1),
        ("K_Ith", 200.0, 250.0),
        ("K_Ic", 250.0, 199.0),
        ("K_Ic", 250.0, math.inf),
        ("w_c", 1e-3, 0.0),
        ("Wg", 4.59e-4, 0.0),
        ("A", 0.02, math.inf),
        ("A", 0.02, math.nan),
        ("delta", 0.7, math.nan),
        ("omega", 4 * math.pi, 0.0),
        ("eps_v", 1e-4, 0.0),
        ("eps_N", 1e-8, -1e-8),
        ("crack_gap0", 0.05, -0.05),
        ("crack_gap0", 0.05, 0.0),
        ("crack_gap0", 0.05, math.nan),
    ],
)
def test_params_valid_traced_each_check(name, good, bad):
    ok = jax.vmap(lambda v: jw.params_valid(jw.Params().replace(**{name: v})))(
        jnp.array([good, bad])
    )
    np.testing.assert_array_equal(np.asarray(ok), [True, False], err_msg=name)


def test_simulate_reports_invalid_traced_parameters(constant_rate_runs):
    # lanes 0 and 2 differ only in lam (1.5 against a traced 0.5 < 1)
    assert constant_rate_runs["lams"][0] == 1.5 and constant_rate_runs["lams"][2] == 0.5
    r = constant_rate_runs["result"]
    names = list(jw.status_name(r.status))
    assert names[2] == "invalid_parameters", names
    assert names[0] == "ok", names


# --- model options --------------------------------------------------------------------


def test_model_options_default_first_and_params_have_the_defaults():
    p = jw.Params()
    assert p.options() == {name: info.choices[0] for name, info in jw.MODEL_OPTIONS.items()}
    assert p.options() == {
        "wedge": "given",
        "normal_stress": "printed",
        "friction_forward": "head",
        "offset": "rest",
        "entries": "segment",
        "numbering": "head",
        "exact": False,
    }


@pytest.mark.parametrize(
    "name,value,choices",
    [
        ("friction_forward", "tailward", "'head' or 'tail'"),
        ("friction_forward", -1, "'head' or 'tail'"),
        ("normal_stress", "stress", "'printed' or 'strain'"),
        ("normal_stress", None, "'printed' or 'strain'"),
        ("entries", "node", "'segment' or 'node_difference' or 'node_mean'"),
    ],
)
def test_model_options_refuse_other_values_naming_option_value_and_choices(name, value, choices):
    with pytest.raises(ValueError, match=re.escape(f"option {name} = {value!r}: need {choices}")):
        jw.Params().replace(**{name: value})


def test_replace_sets_model_options_in_their_groups():
    p = jw.Params().replace(friction_forward="tail", normal_stress="strain", entries="node_mean")
    assert p.body.friction_forward == "tail"
    assert p.soil.normal_stress == "strain"
    assert p.gait.entries == "node_mean"
    assert float(p.body.lam) == 1.5  # lambda stays >= 1: the direction is the option
    with pytest.raises(ValueError, match=r"parameter lam = 0\.5 is out of range"):
        p.replace(lam=0.5)


def test_a_gait_option_on_another_controller_is_refused_by_name():
    from jaxworm import SegmentWave

    p = jw.Params(gait=SegmentWave.from_wave(jw.TravellingWave(), 7))
    with pytest.raises(ValueError, match=r"option entries does not apply to a SegmentWave"):
        p.replace(entries="node_mean")
    assert p.options()["entries"] is None


@pytest.mark.parametrize("name, index", [("A", 1), ("phase", 2)])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_segment_wave_refuses_non_finite_entries_by_name(name, index, bad):
    # Before, a NaN amplitude was accepted and its run took every allowed step before
    # ending invalid_parameters.
    parts = {"A": np.full(6, 0.02), "phase": np.zeros(6)}
    parts[name][index] = bad
    with pytest.raises(ValueError, match=rf"parameter {name}\[{index}\] = {bad!r}: need finite"):
        jw.SegmentWave(**parts)


def test_a_gait_parameter_on_another_controller_is_refused_by_name():
    p = jw.Params(gait=jw.SegmentWave.from_wave(jw.TravellingWave(), 7))
    with pytest.raises(ValueError, match=r"parameter delta does not apply to a SegmentWave"):
        p.replace(delta=0.1)


@pytest.mark.parametrize(
    "bad",
    [[True] * 6, "a", None, [1j] * 6, [[0.02], [0.02, 0.03]]],
    ids=["bools", "string", "none", "complex", "ragged"],
)
def test_segment_wave_refuses_what_is_not_real_numbers_by_name(bad):
    # Bools were taken as 1 m/s amplitudes; the rest failed without naming A.
    with pytest.raises(TypeError, match=r"parameter A = .*: need real numbers \[m/s\]"):
        jw.SegmentWave(A=bad, phase=np.zeros(6))


def test_segment_wave_takes_at_least_one_segment_and_real_sequences():
    with pytest.raises(ValueError, match=r"N − 1 ≥ 1"):
        jw.SegmentWave(A=[], phase=[])
    g = jw.SegmentWave(A=[1, 2, 3], phase=(0, 0.5, 1.0))  # ints and tuples: float64 vectors
    assert g.A.dtype == np.float64 and g.A.shape == (3,) and float(g.phase[1]) == 0.5


@pytest.mark.parametrize("part", ["body", "soil", "gait", "smoothing"])
@pytest.mark.parametrize("bad", ["wave", None, "other part"])
def test_params_refuses_a_part_of_the_wrong_type_by_name(part, bad):
    # The constructor used to take anything; simulate then failed on a missing attribute.
    other = {"body": jw.Soil(), "soil": jw.Body(), "gait": jw.Body(), "smoothing": jw.Soil()}
    value = other[part] if bad == "other part" else bad
    with pytest.raises(TypeError, match=rf"part {part} = .*: need an? \w+, not an? \w+"):
        jw.Params(**{part: value})
    with pytest.raises(TypeError, match=rf"part {part} = "):
        jw.Params().replace(**{part: value})


@pytest.mark.parametrize("name", ["w_c", "Wg"])
def test_soil_numbers_that_cannot_vary_refuse_a_profile_by_name(name):
    # Accepted before, then simulate failed multiplying a tracer by the profile.
    profile = jw.Layered([0.05], [1e-3, 2e-3])
    with pytest.raises(TypeError, match=rf"parameter {name} = Layered\(\.\.\.\): need a number"):
        jw.Soil(**{name: profile})
    with pytest.raises(TypeError, match=rf"parameter {name} = Layered"):
        jw.Params().replace(**{name: profile})
