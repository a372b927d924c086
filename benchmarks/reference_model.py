"""Independent, slow reference implementation of the burrowing-worm model.

Written from the paper ("Burrowing Locomotion via Crack Propagation of a Bio-inspired Soft
Robot", eqs. 1-25, Table 1) and the conventions pinned in MODEL.md, in plain NumPy/SciPy.
It shares no code with `jaxworm` and never imports it: it cross-checks the package
(`tests/test_reference.py`) and is the SciPy anchor of the work-precision study
(`work_precision.py`); tests import it as `benchmarks.reference_model`.

Model (1-based in the comments, 0-based in the code):

- nodes k = 1..N, head k = 1; segment k joins nodes k and k+1, l^k = x_k - x_{k+1};
  node masses m/2 (head, tail) and m (inside), eq. (1).
- tension T^k = EA (l^k / lbar^k - 1); node k feels T^{k-1} - T^k (eqs. 3, 17, 20).
- normal force (eq. 8) F_N^k = max(E_s h (w0 l0 - w_c l^k), 0), the max smoothed as
  eps_N * softplus(z / eps_N).
- friction (eq. 10) F_f^k = mu_s [(lam-1)/2 - (lam+1)/2 sgn(v^k)] F_N^k with
  v^k = (v_k + v_{k+1})/2 (eq. 9) and sgn smoothed as tanh(v / eps_v); node k gets half of
  each adjacent segment's friction (eq. 11).
- back pressure on the head only (eq. 16), Wg given (Table 1 value), not eq. (5).
- K_I (eq. 12); a crack event is an upward crossing of K_I = K_Ic; there x_c jumps to
  eq. (13) and the integration restarts.
- open-loop wave u_k = A sin(omega t + delta k), k = 1..N-1, lbar^k(0) = l0, so
  lbar^k(t) = l0 + (A/omega)(cos(delta k) - cos(omega t + delta k)).
- x_k(0) = -(k-1) l0, v = 0, x_c(0) from eq. (13) at t = 0 (K_I(0) = K_Ith), unless
  `crack_gap0` = x_c(0) - x_1(0) is given.

The integrator is SciPy's `solve_ivp` with an implicit method (LSODA, i.e. BDF on this
stiff system, by default; Radau and BDF also work) and an analytic Jacobian whose blocks
are tridiagonal (assembled dense: the system is tiny).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.special import expit

__all__ = ["DEFAULTS", "ReferenceWorm", "simulate_reference"]

# Table 1 of the paper, plus the smoothing scales of MODEL.md.
DEFAULTS = dict(
    N=7,
    E_s=1.4e5,
    K_Ic=250.0,
    K_Ith=200.0,
    nu=0.3,
    w_c=1e-3,
    Wg=4.59e-4,
    EA=13.0,
    w0=1e-3,
    l0=1e-2,
    h=1e-3,
    m=1e-5,
    mu_s=0.3,
    lam=1.5,
    A=0.02,
    omega=4 * math.pi,
    delta=math.pi / 4,
    eps_v=1e-4,
    eps_N=1e-8,
    crack_gap0=None,
)


class ReferenceWorm:
    """The vector field, its Jacobian and the crack law for one parameter set."""

    def __init__(self, **params):
        unknown = set(params) - set(DEFAULTS)
        if unknown:
            raise TypeError(f"unknown parameters: {sorted(unknown)}")
        p = dict(DEFAULTS)
        p.update(params)
        self.p = p
        N = int(p["N"])
        if N < 2:
            raise ValueError("N >= 2 needed")
        self.N = N
        self.S = N - 1
        masses = np.full(N, float(p["m"]))
        masses[0] *= 0.5
        masses[-1] *= 0.5
        self.masses = masses
        self.inv_m = 1.0 / masses
        self.seg_index = np.arange(1, N)  # k = 1..N-1
        nu = p["nu"]
        # eq. (16): F_p = C_p / ((x_c - x_1) (x_1 - x_2)^2)
        self.C_p = (
            p["E_s"] * p["w0"] ** 2 * p["l0"] ** 2 * p["h"] * p["Wg"] / (2 * math.pi * (1 - nu**2))
        )
        # eq. (12): K_I = C_K / (sqrt(x_c - x_1) (x_1 - x_2))
        self.C_K = p["E_s"] * p["w0"] * p["l0"] / (math.sqrt(2 * math.pi) * (1 - nu**2))

    # --- control ------------------------------------------------------------------
    def lbar(self, t):
        p = self.p
        dk = p["delta"] * self.seg_index
        return p["l0"] + (p["A"] / p["omega"]) * (np.cos(dk) - np.cos(p["omega"] * t + dk))

    # --- initial state and crack law ------------------------------------------------
    def initial_state(self):
        x = -np.arange(self.N) * self.p["l0"]
        v = np.zeros(self.N)
        return np.concatenate([x, v])

    def crack_tip_after_jump(self, x):
        """Eq. (13): the tip position where K_I = K_Ith for the current head."""
        p = self.p
        l1 = x[0] - x[1]
        return x[0] + (p["E_s"] ** 2 * p["w0"] ** 2 * p["l0"] ** 2) / (
            2 * math.pi * p["K_Ith"] ** 2 * (1 - p["nu"] ** 2) ** 2 * l1**2
        )

    def initial_crack_tip(self, x):
        if self.p["crack_gap0"] is None:
            return self.crack_tip_after_jump(x)
        return x[0] + float(self.p["crack_gap0"])

    def stress_intensity(self, x, x_c):
        """Eq. (12)."""
        gap = x_c - x[0]
        if gap <= 0:
            return math.inf
        return self.C_K / (math.sqrt(gap) * (x[0] - x[1]))

    # --- forces -------------------------------------------------------------------------
    def _pieces(self, t, y, x_c):
        p = self.p
        N = self.N
        x = y[:N]
        v = y[N:]
        l = x[:-1] - x[1:]
        lb = self.lbar(t)
        T = p["EA"] * (l / lb - 1.0)
        z = p["E_s"] * p["h"] * (p["w0"] * p["l0"] - p["w_c"] * l)
        s = z / p["eps_N"]
        FN = p["eps_N"] * np.logaddexp(0.0, s)
        vseg = 0.5 * (v[:-1] + v[1:])
        th = np.tanh(vseg / p["eps_v"])
        coef = p["mu_s"] * (0.5 * (p["lam"] - 1) - 0.5 * (p["lam"] + 1) * th)
        Ffs = coef * FN
        gap = x_c - x[0]
        Fp = self.C_p / (gap * l[0] ** 2)
        return x, v, l, lb, T, s, FN, th, coef, Ffs, gap, Fp

    def forces(self, t, y, x_c):
        """Node forces: stretching (-V_s), friction (F_f) and back pressure (-F_p e_1)."""
        x, v, l, lb, T, s, FN, th, coef, Ffs, gap, Fp = self._pieces(t, y, x_c)
        N = self.N
        stretch = np.zeros(N)
        stretch[:-1] -= T
        stretch[1:] += T
        fric = np.zeros(N)
        fric[:-1] += 0.5 * Ffs
        fric[1:] += 0.5 * Ffs
        back = np.zeros(N)
        back[0] = -Fp
        return stretch, fric, back

    def rhs(self, t, y, x_c):
        stretch, fric, back = self.forces(t, y, x_c)
        return np.concatenate([y[self.N :], (stretch + fric + back) * self.inv_m])

    def jac(self, t, y, x_c):
        p = self.p
        N = self.N
        x, v, l, lb, T, s, FN, th, coef, Ffs, gap, Fp = self._pieces(t, y, x_c)
        J = np.zeros((2 * N, 2 * N))
        J[:N, N:] = np.eye(N)
        # d(node force)/dx, tridiagonal. Segment j joins nodes j, j+1 (0-based) and
        # depends on x_j - x_{j+1}; its force enters node j with sign sj, node j+1 with sj1.
        dT_dl = p["EA"] / lb
        dFN_dl = expit(s) * (-p["E_s"] * p["h"] * p["w_c"])
        dFfs_dl = coef * dFN_dl
        dc_dv = -0.5 * (p["lam"] + 1) * p["mu_s"] * (1.0 - th**2) / p["eps_v"]
        dFfs_dvseg = dc_dv * FN  # d/dv_j = d/dv_{j+1} = 0.5 * this
        Kx = np.zeros((N, N))
        Kv = np.zeros((N, N))
        for j in range(N - 1):
            # node j: -T_j + Ffs_j/2 ; node j+1: +T_j + Ffs_j/2
            a = -dT_dl[j] + 0.5 * dFfs_dl[j]  # d(node j force)/dl_j
            b = dT_dl[j] + 0.5 * dFfs_dl[j]  # d(node j+1 force)/dl_j
            Kx[j, j] += a
            Kx[j, j + 1] -= a
            Kx[j + 1, j] += b
            Kx[j + 1, j + 1] -= b
            c = 0.25 * dFfs_dvseg[j]  # d(node force)/dv_j, same for v_{j+1}
            Kv[j, j] += c
            Kv[j, j + 1] += c
            Kv[j + 1, j] += c
            Kv[j + 1, j + 1] += c
        # back pressure -F_p on node 0, F_p = C_p / (gap l_0^2)
        Kx[0, 0] -= Fp * (1.0 / gap - 2.0 / l[0])
        Kx[0, 1] -= Fp * (2.0 / l[0])
        J[N:, :N] = Kx * self.inv_m[:, None]
        J[N:, N:] = Kv * self.inv_m[:, None]
        return J


def simulate_reference(
    t1, rtol=1e-8, atol=1e-11, method="LSODA", max_cracks=200, first_step=None, **params
):
    """Simulate from rest over [0, t1] with the crack restart loop.

    Between cracks SciPy's `solve_ivp` integrates with an implicit method (`method`:
    "LSODA" by default, which runs BDF on this stiff system; "Radau" and "BDF" work too)
    and the analytic Jacobian; a terminal event with direction +1 finds the upward
    crossing K_I = K_Ic, where x_c jumps by eq. (13) and the solve restarts.

    `atol` is the absolute tolerance on positions [m]; velocities get `1e3 * atol` [m/s]
    (a position error e on the elastic mode, ~1e4 rad/s, comes with a velocity error
    ~1e4 e, and velocities matter only through friction, smoothed over eps_v = 1e-4 m/s).

    Returns a dict: mean_velocity [m/s] (plain mean of node positions), n_cracks,
    crack_times, crack_tips (x_c after each jump), x_final, v_final, x_c (final tip),
    K_I_final (K_I at t1), K_I_max_last (largest K_I at the solver's steps after the last
    crack: the margin below K_Ic that keeps the crack count robust), and solver counts.
    """
    worm = ReferenceWorm(**params)
    p = worm.p
    N = worm.N
    y = worm.initial_state()
    x0 = y[:N].copy()
    x_c = worm.initial_crack_tip(x0)
    atol_vec = np.concatenate([np.full(N, atol), np.full(N, atol * 1e3)])
    t = 0.0
    crack_times, crack_tips = [], []
    if worm.stress_intensity(x0, x_c) >= p["K_Ic"]:  # already critical: it jumps at t = 0
        x_c = worm.crack_tip_after_jump(x0)
        crack_times.append(0.0)
        crack_tips.append(x_c)
    nfev = njev = nsteps = 0

    while True:
        xc_now = x_c

        def event(tt, yy, xc=xc_now):
            # K_I - K_Ic written without the singular 1/sqrt: same sign, same roots,
            # since K_I >= K_Ic  <=>  C_K >= K_Ic sqrt(gap) l^1  (gap > 0, l^1 > 0).
            gap = xc - yy[0]
            l1 = yy[0] - yy[1]
            return worm.C_K - p["K_Ic"] * math.sqrt(max(gap, 0.0)) * l1

        event.terminal = True
        event.direction = 1
        sol = solve_ivp(
            lambda tt, yy, xc=xc_now: worm.rhs(tt, yy, xc),
            (t, t1),
            y,
            method=method,
            rtol=rtol,
            atol=atol_vec,
            jac=lambda tt, yy, xc=xc_now: worm.jac(tt, yy, xc),
            events=event,
            first_step=first_step,
        )
        if sol.status < 0:
            raise RuntimeError(f"reference solve failed at t={sol.t[-1]}: {sol.message}")
        nfev += sol.nfev
        njev += sol.njev
        nsteps += len(sol.t) - 1
        if sol.status == 1 and len(sol.t_events[0]):
            t = float(sol.t_events[0][0])
            y = np.array(sol.y_events[0][0])
            x_c = worm.crack_tip_after_jump(y[:N])
            crack_times.append(t)
            crack_tips.append(x_c)
            if len(crack_times) > max_cracks:
                raise RuntimeError("too many cracks")
            if t >= t1:
                K_I_max_last = worm.stress_intensity(y[:N], x_c)
                break
            continue
        y = sol.y[:, -1]
        K_I_max_last = max(
            worm.stress_intensity(sol.y[:N, i], xc_now) for i in range(sol.y.shape[1])
        )
        break

    x = y[:N]
    return dict(
        mean_velocity=float((x.mean() - x0.mean()) / t1),
        n_cracks=len(crack_times),
        crack_times=crack_times,
        crack_tips=crack_tips,
        x_final=x.copy(),
        v_final=y[N:].copy(),
        x_c=float(x_c),
        K_I_final=worm.stress_intensity(x, x_c),
        K_I_max_last=float(K_I_max_last),
        nfev=nfev,
        njev=njev,
        nsteps=nsteps,
        params=p,
    )
