"""Model parameters: Table 1 of the paper, as typed equinox modules.

Every numeric field is a float64 array leaf, so parameters pass through `jax.jit`,
`jax.vmap` and `jax.grad` unchanged. Python values are checked at construction and the
error names the parameter, the value given and the allowed range; values that arrive
traced are checked inside the solve instead (see `params_valid`) and reported in the
result's status.
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._control import AbstractController, TravellingWave, keep_type
from ._physics import Scalar
from ._soil import AbstractProfile, is_profile, value_at
from ._validation import (
    check_choice as _check_choice,
)
from ._validation import (
    check_int as _check_int,
)
from ._validation import (
    check_range as _check_range,
)
from ._validation import (
    check_t1 as _check_t1,
)
from ._validation import (
    concrete as _concrete,
)
from ._validation import (
    show as _show,
)
from ._validation import (
    static_int as _static_int,
)
from ._validation import (
    to_float as _to_float,
)

__all__ = [
    "Body",
    "Soil",
    "Smoothing",
    "Params",
    "FLAT_NAMES",
    "PARTS",
    "ParamInfo",
    "PARAMETER_INFO",
    "OptionInfo",
    "MODEL_OPTIONS",
    "ascii_unit",
    "params_valid",
    "speed_bound",
    "N_MAX",
    "EPS_V_MAX",
    "EPS_N_MAX",
]

#: Largest number of nodes: N sets array shapes, and bodies beyond ~100 nodes are
#: untested; 1000 keeps a typo such as N = 1e300 from reaching the compiler.
N_MAX = 1000
#: Largest smoothing widths: the largest `benchmarks/smoothing.py` measured. eps_v =
#: 1e-3 m/s already moves the mean velocity by 2-3 % (`benchmarks/results/smoothing/smoothing.md`);
#: wider, tanh(v/eps_v) stays far from ±1 at the gait's speeds (~A = 0.02 m/s) and the
#: constant term of the friction law (eq. 10) pushes the worm forward on its own
#: (eps_v = 1 m/s was seen at 0.17 m/s, 10x the true speed). eps_N = 1e-6 N moves it
#: by 5e-4; the normal forces are ~1e-4 N.
EPS_V_MAX = 1e-3
EPS_N_MAX = 1e-6


class Body(eqx.Module):
    """The segmented worm body (§2.1, Table 1).

    **Fields** (SI units):

    - `N`: number of nodes (static int, ≥ 2); there are N − 1 segments. Default 7.
    - `EA`: stretching stiffness of a segment [N] (Table 1 writes Pa·m²). Default 13.
    - `w0`: unstretched segment width w_0 [m]. Default 1e-3.
    - `l0`: unstretched segment length l_0 [m]. Default 1e-2.
    - `h`: planar (out-of-plane) thickness of body and crack [m]. Default 1e-3.
    - `m`: mass per segment m^k [kg]; node masses are m/2 at head and tail, m inside
      (eq. 1). Default 1e-5.
    - `lam`: bristle anisotropy λ ≥ 1: friction opposing backward motion is λ μ_s
      (eq. 10). Default 1.5.
    - `friction_forward`: static option, the direction eq. (10) calls forward.
      `"head"` (default): a segment moving tail-ward meets λ μ_s, head-ward μ_s.
      `"tail"`: the reverse (the bristles grip against head-ward motion), with the same
      λ ≥ 1. With the wave mirrored too (δ → −δ) and the crack forces negligible,
      `"tail"` maps the body's mean velocity v̄ to −v̄ (the body seen from its tail).
    """

    N: int = eqx.field(static=True, default=7, converter=_static_int)
    EA: Float[Array, ""] = eqx.field(default=13.0, converter=_to_float)
    w0: Float[Array, ""] = eqx.field(default=1e-3, converter=_to_float)
    l0: Float[Array, ""] = eqx.field(default=1e-2, converter=_to_float)
    h: Float[Array, ""] = eqx.field(default=1e-3, converter=_to_float)
    m: Float[Array, ""] = eqx.field(default=1e-5, converter=_to_float)
    lam: Float[Array, ""] = eqx.field(default=1.5, converter=_to_float)
    friction_forward: Literal["head", "tail"] = eqx.field(static=True, default="head")

    def __check_init__(self):
        _check_int("N", self.N, 2, N_MAX)
        for name in ("EA", "w0", "l0", "h", "m"):
            _check_range(name, getattr(self, name), lambda v: v > 0, "> 0")
        _check_range("lam", self.lam, lambda v: v >= 1, ">= 1")
        _check_choice("friction_forward", self.friction_forward, ("head", "tail"))

    @property
    def node_masses(self) -> Float[Array, " N"]:
        """Lumped node masses m_k (eq. 1): m/2 at head and tail, m elsewhere [kg]."""
        ones = jnp.ones(self.N).at[0].set(0.5).at[-1].set(0.5)
        return ones * self.m


class Soil(eqx.Module):
    """The soil and the worm-soil interface (§2.3, §3.1, Table 1).

    **Fields** (SI units):

    - `E_s`: soil elasticity [Pa]. Default 1.4e5.
    - `K_Ic`: critical stress intensity factor [Pa·√m]: the crack jumps when K_I
      reaches it (eq. 12). Default 250.
    - `K_Ith`: threshold stress intensity factor [Pa·√m]: the crack arrests where
      K_I = K_Ith (eq. 13). 0 < K_Ith < K_Ic. Default 200.
    - `nu`: Poisson's ratio, 0 ≤ ν < 0.5. Default 0.3.
    - `w_c`: crack width [m]. Default 1e-3.
    - `Wg`: wedge number [-] in the back pressure (eqs. 15-16). Default 4.59e-4
      (Table 1).
    - `mu_s`: sliding friction coefficient μ_s ≥ 0 (eq. 10). Default 0.3.
    - `wedge`: static option. `"given"` (default) uses `Wg` as Table 1 gives it;
      `"eq5"` derives Wg = K_Ic² w_c / (E_s² h w0) from eq. (5) instead. The two
      disagree for Table 1's values (4.59e-4 against 3.19e-3); the paper does not say
      which it used.
    - `normal_stress`: static option, how eq. (7) is read. `"printed"` (default):
      σ_N = E_s (w − w_c) as printed (units Pa·m), F_N = E_s h (w_0 l_0 − w_c l) (eq. 8).
      `"strain"`: σ_N = E_s (w − w_c)/w_c, a stress, so F_N is 1/w_c (1000× for
      Table 1) times larger. Friction then competes with the segments' springs: a
      stiff case (`benchmarks/results/readings/`).

    **Soil that varies along the burrow.** `E_s`, `K_Ic`, `K_Ith` and `mu_s` each take a
    number (homogeneous, as Table 1) or a profile of position x [m] (`Layered`,
    `Gradient`, `RandomField`; docs: Soil). The fracture constants K_Ic, K_Ith and
    the E_s of K_I (eq. 12) and of the back pressure (eq. 16) are those at the crack tip
    x_c; the E_s and μ_s of the normal force and friction (eqs. 8, 10) those at each
    segment's midpoint. After a crack the tip stops at the first x ahead of the old tip
    with K_I(x) ≤ K_Ith(x) (`arrest_tip`). K_Ith < K_Ic is checked at each profile's
    `points`. A number pays nothing: the model evaluates a profile only where one is
    given.

    ```python
    soil = Soil(K_Ic=Layered([0.05], [250.0, 500.0]), K_Ith=Layered([0.05], [200.0, 400.0]))
    ```
    """

    E_s: Float[Array, ""] | AbstractProfile = eqx.field(default=1.4e5, converter=_to_float)
    K_Ic: Float[Array, ""] | AbstractProfile = eqx.field(default=250.0, converter=_to_float)
    K_Ith: Float[Array, ""] | AbstractProfile = eqx.field(default=200.0, converter=_to_float)
    nu: Float[Array, ""] = eqx.field(default=0.3, converter=_to_float)
    w_c: Float[Array, ""] = eqx.field(default=1e-3, converter=_to_float)
    Wg: Float[Array, ""] = eqx.field(default=4.59e-4, converter=_to_float)
    mu_s: Float[Array, ""] | AbstractProfile = eqx.field(default=0.3, converter=_to_float)
    wedge: Literal["given", "eq5"] = eqx.field(static=True, default="given")
    normal_stress: Literal["printed", "strain"] = eqx.field(static=True, default="printed")

    def __check_init__(self):
        for name in ("E_s", "K_Ic", "K_Ith"):
            _check_property(name, getattr(self, name), lambda v: v > 0, "> 0")
        for name in ("w_c", "Wg"):
            if is_profile(getattr(self, name)):
                raise TypeError(
                    f"parameter {name} = {type(getattr(self, name)).__name__}(...): need a "
                    "number; only E_s, K_Ic, K_Ith and mu_s vary along the burrow"
                )
            _check_range(name, getattr(self, name), lambda v: v > 0, "> 0")
        _check_range("nu", self.nu, lambda v: (v >= 0) & (v < 0.5), "in [0, 0.5)")
        _check_property("mu_s", self.mu_s, lambda v: v >= 0, ">= 0")
        if is_profile(self.K_Ic) or is_profile(self.K_Ith):
            _check_below_profiles(self.K_Ith, self.K_Ic)
        elif _concrete(self.K_Ith) and _concrete(self.K_Ic):
            bad = np.asarray(self.K_Ith) >= np.asarray(self.K_Ic)
            if np.any(bad):
                raise ValueError(
                    f"parameter K_Ith = {_show(self.K_Ith)} is out of range: need "
                    f"0 < K_Ith < K_Ic = {_show(self.K_Ic)}"
                )
        if self.wedge not in ("given", "eq5"):
            raise ValueError(f"option wedge = {self.wedge!r}: need 'given' or 'eq5'")
        _check_choice("normal_stress", self.normal_stress, ("printed", "strain"))


def _check_property(name: str, value, ok, allowed: str) -> None:
    """`check_range` for a number, the profile's own check for a profile."""
    if is_profile(value):
        value.check(name, ok, allowed)
    else:
        _check_range(name, value, ok, allowed)


def _profile_points(*values) -> Float[Array, " P"]:
    """The positions where the profiles among `values` are compared."""
    return jnp.concatenate([v.points() for v in values if is_profile(v)])


def _check_below_profiles(K_Ith, K_Ic) -> None:
    """Refuse K_Ith ≥ K_Ic at any of the profiles' points, naming the first such point."""
    x = _profile_points(K_Ith, K_Ic)
    lower = jnp.broadcast_to(value_at(K_Ith, x), x.shape)
    upper = jnp.broadcast_to(value_at(K_Ic, x), x.shape)
    if not (_concrete(lower) and _concrete(upper)):
        return
    bad = np.flatnonzero(~(np.asarray(lower) < np.asarray(upper)))
    if bad.size:
        i = int(bad[np.argmin(np.asarray(x)[bad])])
        raise ValueError(
            f"parameter K_Ith = {_show(lower[i])} at x = {float(x[i]):g} m is out of range: "
            f"need 0 < K_Ith < K_Ic = {_show(upper[i])} at every position"
        )


class Smoothing(eqx.Module):
    """Smoothing of the non-smooth terms of the model (see `MODEL.md`).

    - `eps_v`: velocity scale of the smooth sign, sgn(v) ≈ tanh(v / eps_v) [m/s].
      Default 1e-4; 0 < eps_v ≤ `EPS_V_MAX` = 1e-3. eps_v → 0 recovers the paper.
    - `eps_N`: force scale of the smooth max used in the normal force (eq. 8),
      max(z, 0) ≈ eps_N·softplus(z / eps_N) [N]. Default 1e-8 N, small against the
      normal forces (~1e-4 N); 0 < eps_N ≤ `EPS_N_MAX` = 1e-6.
    - `exact`: static; `True` uses the exact sign and max (for reference runs; the
      vector field is then discontinuous and adaptive solvers slow down at each switch).
    """

    eps_v: Float[Array, ""] = eqx.field(default=1e-4, converter=_to_float)
    eps_N: Float[Array, ""] = eqx.field(default=1e-8, converter=_to_float)
    exact: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        _check_range(
            "eps_v",
            self.eps_v,
            lambda v: (v > 0) & (v <= EPS_V_MAX),
            f"> 0 and <= {EPS_V_MAX:g} m/s",
        )
        _check_range(
            "eps_N", self.eps_N, lambda v: (v > 0) & (v <= EPS_N_MAX), f"> 0 and <= {EPS_N_MAX:g} N"
        )
        if not isinstance(self.exact, bool):
            raise TypeError(f"option exact = {_show(self.exact)}: need True or False")


class Params(eqx.Module):
    """All model parameters: `body`, `soil`, `gait` (the controller) and `smoothing`.

    `crack_gap0` is the initial distance x_c(0) − x_1(0) [m]; `None` (default, as
    `MODEL.md` pins) places the tip by eq. (13) at t = 0, so that K_I(0) = K_Ith. A gap
    short enough that K_I(0) ≥ K_Ic makes the crack jump at t = 0 (`simulate`).

    ```python
    p = Params()                                  # Table 1
    p = p.replace(omega=3 * jnp.pi, E_s=2e5)      # by the flat names of the CLI
    ```
    """

    body: Body = eqx.field(default_factory=Body)
    soil: Soil = eqx.field(default_factory=Soil)
    gait: AbstractController = eqx.field(default_factory=TravellingWave)
    smoothing: Smoothing = eqx.field(default_factory=Smoothing)
    crack_gap0: Float[Array, ""] | None = eqx.field(default=None, converter=_to_float)

    def __check_init__(self):
        for name, kind in _PART_TYPES.items():
            _check_part(name, getattr(self, name), kind)
        if self.crack_gap0 is not None:
            _check_range("crack_gap0", self.crack_gap0, lambda v: v > 0, "> 0")

    def replace(self, **values) -> Params:
        """A copy with parameters set by their flat names (`FLAT_NAMES`), model options
        by theirs (`MODEL_OPTIONS`) and whole parts by theirs (`PARTS`: `body`, `soil`,
        `gait`, `smoothing`), validated: a wrong type raises `TypeError`, a value out of
        range `ValueError`, each naming the parameter, the value and what is allowed.
        A part and a parameter within it cannot both be given."""
        groups: dict[str, dict] = {}
        top: dict = {}
        for name, value in values.items():
            if name in PARTS:
                _check_part(name, value, _PART_TYPES[name])
                top[name] = value
                continue
            if name in FLAT_NAMES:
                group = FLAT_NAMES[name]
            elif name in MODEL_OPTIONS:
                group = MODEL_OPTIONS[name].group
            else:
                raise ValueError(
                    f"unknown parameter {name!r}; known: {', '.join(sorted(FLAT_NAMES))}; "
                    f"model options: {', '.join(MODEL_OPTIONS)}; parts: {', '.join(PARTS)}"
                )
            if group is None:
                top[name] = value
            else:
                groups.setdefault(group, {})[name] = value
        both = sorted(set(groups) & set(top))
        if both:
            raise ValueError(
                f"parameters {', '.join(sorted(groups[both[0]]))} and the part {both[0]} "
                "are both given: give the part with them set, or them alone"
            )
        for group, kw in groups.items():
            owner = getattr(self, group)
            unknown = [n for n in kw if not hasattr(owner, n)]
            if unknown:
                kind = "option" if unknown[0] in MODEL_OPTIONS else "parameter"
                own = [n for n in FLAT_NAMES if FLAT_NAMES[n] == group and hasattr(owner, n)]
                raise ValueError(
                    f"{kind} {unknown[0]} does not apply to a {type(owner).__name__} (the "
                    f"{group}); its parameters by flat name: {', '.join(own) or 'none'}"
                )
        new = {g: dataclasses.replace(getattr(self, g), **kw) for g, kw in groups.items()}
        return dataclasses.replace(self, **new, **top)

    def options(self) -> dict:
        """The model options by their names (`MODEL_OPTIONS`), None for an option the
        gait does not have (a controller other than `TravellingWave`)."""
        return {
            name: getattr(getattr(self, info.group), name, None)
            for name, info in MODEL_OPTIONS.items()
        }

    def flat(self) -> dict:
        """The parameters by their flat names (those the gait carries included)."""
        out = {}
        for name, group in FLAT_NAMES.items():
            owner = self if group is None else getattr(self, group)
            if hasattr(owner, name):
                out[name] = getattr(owner, name)
        return out

    @property
    def wedge_number(self) -> Float[Array, ""]:
        """Wg used in the back pressure: `soil.Wg`, or eq. (5) when `soil.wedge == 'eq5'`
        (for soil that varies, `wedge_number_at` the crack tip)."""
        return self.wedge_number_at(None)

    def wedge_number_at(self, x_c) -> Float[Array, ""]:
        """Wg with the soil at the crack tip x_c [m] (eq. 5 with K_Ic(x_c), E_s(x_c) when
        `soil.wedge == 'eq5'`); `x_c` is not used for homogeneous soil."""
        s, b = self.soil, self.body
        if s.wedge == "eq5":
            K_Ic, E_s = s.K_Ic, s.E_s
            if isinstance(K_Ic, AbstractProfile) or isinstance(E_s, AbstractProfile):
                if x_c is None:
                    raise ValueError("wedge_number: the soil varies; use wedge_number_at(x_c)")
                K_Ic, E_s = value_at(K_Ic, x_c), value_at(E_s, x_c)
            return K_Ic**2 * s.w_c / (E_s**2 * b.h * b.w0)
        return s.Wg


def _check_part(name: str, value, kind: type) -> None:
    """Refuse a part of `Params` (`PARTS`) that is not a `kind`, naming it."""
    if not isinstance(value, kind):
        raise TypeError(
            f"part {name} = {_show(value)}: need {_a(kind.__name__)}, "
            f"not {_a(type(value).__name__)}"
        )


def _a(noun: str) -> str:
    return f"{'an' if noun[0] in 'AEIOUaeiou' else 'a'} {noun}"


#: The type each part of `Params` must have.
_PART_TYPES = {
    "body": Body,
    "soil": Soil,
    "gait": AbstractController,
    "smoothing": Smoothing,
}


class ParamInfo(NamedTuple):
    """What a user is told about one parameter, set by its flat name."""

    #: The field of `Params` that holds it ("body", "soil", "gait", "smoothing"), or None
    #: for a field of `Params` itself.
    group: str | None
    #: SI unit, "-" when dimensionless (`ascii_unit` spells it for files).
    unit: str
    #: The default as users read it ("4*pi", "1e-3"): the field's default, written out.
    default: str
    #: What it is, in a few words.
    doc: str


#: Every parameter by its flat name (the name `Params.replace`, the sweep grids, the
#: optimiser's bounds and `jaxworm simulate --set` take), in the order `jaxworm simulate
#: --help` lists them: Table 1's parameters, then the smoothing scales and the initial
#: crack gap. `FLAT_NAMES`, the units in result files and the command line's parameter
#: table and help derive from it.
PARAMETER_INFO: dict[str, ParamInfo] = {
    "N": ParamInfo("body", "-", "7", "number of nodes (integer >= 2)"),
    "E_s": ParamInfo("soil", "Pa", "1.4e5", "soil elasticity"),
    "K_Ic": ParamInfo("soil", "Pa·√m", "250", "critical stress intensity factor"),
    "K_Ith": ParamInfo("soil", "Pa·√m", "200", "threshold stress intensity factor (< K_Ic)"),
    "nu": ParamInfo("soil", "-", "0.3", "Poisson's ratio, in [0, 0.5)"),
    "w_c": ParamInfo("soil", "m", "1e-3", "crack width"),
    "Wg": ParamInfo("soil", "-", "4.59e-4", "wedge number"),
    "EA": ParamInfo("body", "N", "13", "stretching stiffness (Table 1 writes Pa·m²)"),
    "w0": ParamInfo("body", "m", "1e-3", "unstretched segment width"),
    "l0": ParamInfo("body", "m", "1e-2", "unstretched segment length"),
    "h": ParamInfo("body", "m", "1e-3", "planar thickness"),
    "m": ParamInfo("body", "kg", "1e-5", "mass per segment"),
    "mu_s": ParamInfo("soil", "-", "0.3", "sliding friction coefficient"),
    "lam": ParamInfo("body", "-", "1.5", "friction anisotropy multiplier (>= 1)"),
    "A": ParamInfo("gait", "m/s", "0.02", "gait amplitude"),
    "omega": ParamInfo("gait", "rad/s", "4*pi", "gait angular frequency (> 0)"),
    "delta": ParamInfo("gait", "rad", "pi/4", "gait phase offset between segments"),
    "eps_v": ParamInfo("smoothing", "m/s", "1e-4", "smoothing scale of sgn: tanh(v/eps_v)"),
    "eps_N": ParamInfo("smoothing", "N", "1e-8", "smoothing scale of max in the normal force"),
    "crack_gap0": ParamInfo(None, "m", "eq. 13", "initial crack tip distance ahead of the head"),
}


class OptionInfo(NamedTuple):
    """What a user is told about one model option (a static choice of reading)."""

    #: The field of `Params` that holds it ("body", "soil", "gait", "smoothing").
    group: str
    #: The values it takes, the default first.
    choices: tuple
    #: What it is, in a few words.
    doc: str


#: Every model option by name: each pins a reading of the paper (`docs/MODEL.md`), is a
#: static field of the group that holds it, and takes one of its `choices`, the default
#: (today's reading) first. `Params.replace` sets them by these names and
#: `Params.options` lists them.
MODEL_OPTIONS: dict[str, OptionInfo] = {
    "wedge": OptionInfo("soil", ("given", "eq5"), "Wg as given (Table 1) or from eq. 5"),
    "normal_stress": OptionInfo(
        "soil",
        ("printed", "strain"),
        "eq. 7 as printed, sigma_N = E_s (w - w_c), or as a strain, E_s (w - w_c)/w_c",
    ),
    "friction_forward": OptionInfo(
        "body",
        ("head", "tail"),
        "the direction eq. 10 calls forward: motion the other way meets lam*mu_s",
    ),
    "offset": OptionInfo(
        "gait", ("rest", "centred"), "travelling-wave intrinsic lengths start at l0 or centre on it"
    ),
    "entries": OptionInfo(
        "gait",
        ("segment", "node_difference", "node_mean"),
        "eq. 24's entries: one per segment, or N node entries combined per segment",
    ),
    "numbering": OptionInfo(
        "gait", ("head", "tail"), "eq. 25 counts k from the head, or from the tail"
    ),
    "exact": OptionInfo("smoothing", (False, True), "exact sgn and max instead of smoothed"),
}


#: The field of `Params` that holds each flat name (None: `Params` itself), grouped in the
#: order of the fields of `Params`, in `PARAMETER_INFO`'s order within each.
FLAT_NAMES: dict[str, str | None] = dict(
    sorted(
        ((name, info.group) for name, info in PARAMETER_INFO.items()),
        key=lambda item: [f.name for f in dataclasses.fields(Params)].index(item[1] or item[0]),
    )
)


#: The parts of `Params` that `Params.replace` sets whole, by their field names.
PARTS = ("body", "soil", "gait", "smoothing")


def ascii_unit(unit: str) -> str:
    """`unit` in plain ASCII, as result files write it: `Pa·√m` is `Pa m^0.5`."""
    return unit.replace("·", " ").replace("√m", "m^0.5").replace("²", "^2")


def params_valid(p: Params) -> Bool[Array, ""]:
    """The construction-time checks, as a traced boolean (for values under transforms)."""
    b, s, sm = p.body, p.soil, p.smoothing
    leaves = [x for x in jax.tree_util.tree_leaves(p) if eqx.is_inexact_array(x)]
    ok = jnp.all(jnp.array([jnp.all(jnp.isfinite(x)) for x in leaves]))
    positive = [b.EA, b.w0, b.l0, b.h, b.m, s.E_s, s.K_Ic, s.K_Ith, s.w_c, s.Wg, sm.eps_v, sm.eps_N]
    for x in positive:
        ok = ok & (x.valid(lambda v: v > 0) if isinstance(x, AbstractProfile) else (x > 0))
    mu = s.mu_s
    mu_ok = mu.valid(lambda v: v >= 0) if isinstance(mu, AbstractProfile) else (mu >= 0)
    ok = ok & (b.lam >= 1) & mu_ok & (s.nu >= 0) & (s.nu < 0.5)
    ok = ok & (sm.eps_v <= EPS_V_MAX) & (sm.eps_N <= EPS_N_MAX)
    K_Ic, K_Ith = s.K_Ic, s.K_Ith
    if isinstance(K_Ic, AbstractProfile) or isinstance(K_Ith, AbstractProfile):
        x = _profile_points(K_Ith, K_Ic)
        ok = ok & jnp.all(value_at(K_Ith, x) < value_at(K_Ic, x))
    else:
        ok = ok & (K_Ith < K_Ic)
    ok = ok & p.gait.valid()
    if p.crack_gap0 is not None:
        ok = ok & (p.crack_gap0 > 0)
    return ok


def speed_bound(p: Params, t1: Scalar) -> Float[Array, ""]:
    """The highest mean forward velocity v̄ over [0, t1] [m/s] the gait's stroke allows:

        v̄ ≤ S(t1) + (N − 1) l_0 / t1,   S(t1) = (1/t1) ∫_0^t1 Σ_k |u_k| dt,

    for the travelling wave S = (N − 1)|A| min(1, 2⌈ωt1/π⌉/(ωt1)) (→ (N − 1)·2|A|/π =
    0.076 m/s for Table 1, five times the fastest gaits seen, ~0.016 m/s). A run
    faster than this is reported `implausible_speed`, never `ok`; +inf (no check) for a
    controller that gives no `stroke_speed`.

    Why: the soil pushes the worm forward only through friction (the back pressure
    pushes it back), and by eq. (10) friction pushes a node forward only while that
    node moves backward. So while the body advances some node is at rest or moving
    back, and no node moves faster than it by more than the rates of change of the
    segments between them, Σ|dl_k/dt|: the intrinsic rates |u_k| (each half period of
    the wave strokes a segment by 2|A|/ω) plus the elastic strain's. The strain and the
    shape of the body change the node mean by less than one body length (N − 1) l_0
    unless a segment inverts or doubles: that is the second term (it matters only over
    short horizons). The smoothed sign pushes forward too, below ~0.2 eps_v ≤ 2e-4 m/s
    (`EPS_V_MAX`), within the margin. Backward speeds are not bounded this way: the
    back pressure alone can push the worm back (with μ_s = 0, indefinitely).
    """
    t1 = _check_t1(t1)  # a number > 0 (a traced t1 is the solve's to check)
    stroke = p.gait.stroke_speed(p.body, t1)
    if stroke is None:
        return jnp.asarray(jnp.inf)
    return stroke + (p.body.N - 1) * p.body.l0 / t1


def placeholder(p: Params) -> Params:
    """Valid parameters of `p`'s structure (Table 1 values, the same static options and
    N), run in place of an invalid lane so that it takes no step (`simulate`)."""
    return Params(
        body=Body(N=p.body.N, friction_forward=p.body.friction_forward),
        soil=Soil(
            wedge=p.soil.wedge,
            normal_stress=p.soil.normal_stress,
            **{
                name: getattr(p.soil, name).placeholder(float(getattr(Soil, name)))
                for name in ("E_s", "K_Ic", "K_Ith", "mu_s")
                if is_profile(getattr(p.soil, name))
            },
        ),
        gait=keep_type(p.gait, p.gait.placeholder()),
        smoothing=Smoothing(exact=p.smoothing.exact),
        crack_gap0=None if p.crack_gap0 is None else 1.0,
    )
