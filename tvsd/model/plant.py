"""The scanning-aperture drive, paper eqs. (9)–(11), as one numba kernel with the effects library.

    φ̇ = ω
    J·ω̇ = kM·i − kv·ω − τf − J·Δv + τ_effects(φ, t)
    L·i̇ = −kb·ω − R·i + ku·u_applied

Integration (MODEL-NOTES §7): RK4 for (φ, ω, i) with u, τf and the OU acceleration held over the
step; the exact exponential step for the LuGre state z (tvsd.model.lugre); the literal SDE's noise
(eq. 12) as an additive Euler–Maruyama increment after the step. At dt = 1e-4 s this matches a
1e-7 s reference to ≤ 0.3 % in settling time.

`run` simulates one run: open loop (u given per step) or closed loop with the robust law in
position or scanning mode (scanning adds the model's feedforward voltage when asked, so the
law only corrects around it). It writes decimated rows into a preallocated output array and allocates
nothing per step, so it also serves as the SIL plant's inner loop.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tvsd.control.law import robust_law
from tvsd.model import effects as E
from tvsd.model import params as P
from tvsd.model.lugre import lugre_step, stribeck

# Controller array layout; C_MODE: 0 open loop (u from the input array), 1 position, 2 scanning.
C_MODE, C_GP, C_GD, C_GR, C_G0, C_UMAX, C_REF, C_ACCEL, C_MAXLAG, C_FF, C_DIV = range(11)
N_CTRL = 11  # C_DIV: plant steps per controller update (the law and u_in update every C_DIV steps)
MODE_OPEN, MODE_POSITION, MODE_SCAN = 0, 1, 2

# Output columns (one row every `decim` steps).
O_T, O_U, O_UAPP, O_PHI, O_OMEGA, O_I, O_Z, O_OMEGA_MEAN, O_DIST_MEAN, O_PHI_REF, O_U_MEAN = range(11)
N_OUT = 11
# State array layout (initial state in, final state out).
# S_TIME (plant time at the start of the next call) and S_RING_POS (the delay ring's write
# position) carry a run across calls: a caller that steps the plant tick by tick (the control
# thread, the MCU bridge) keeps fixed-frequency effects continuous and, with state_array(),
# the delay ring in the state itself, so a call allocates nothing.
S_PHI, S_OMEGA, S_I, S_Z, S_NOISE, S_TIME, S_RING_POS = range(7)
N_STATE = 7
MAX_DELAY_S = 0.1  # the effects library's largest delay_s


def state_array(dt: float) -> np.ndarray:
    """A state with room for the delay ring of any delay the effects library allows."""
    return np.zeros(N_STATE + int(MAX_DELAY_S / dt) + 2)


@njit(cache=True, nogil=True)
def _seed(seed: int) -> None:
    np.random.seed(seed)


@njit(cache=True, nogil=True, inline="always")
def _shaft_torque(phi: float, t: float, eff: np.ndarray) -> float:
    """Deterministic torques of the effects library (imbalance, cogging, resonance), N·m."""
    tau = 0.0
    if eff[E.E_IMB_AMP] != 0.0:
        tau += eff[E.E_IMB_AMP] * math.sin(phi + eff[E.E_IMB_PHASE])
    if eff[E.E_COG_AMP] != 0.0:
        tau += eff[E.E_COG_AMP] * math.sin(eff[E.E_COG_ORDER] * phi + eff[E.E_COG_PHASE])
    if eff[E.E_RES_AMP] != 0.0:
        tau += eff[E.E_RES_AMP] * math.sin(2.0 * math.pi * eff[E.E_RES_FREQ] * t + eff[E.E_RES_PHASE])
    return tau


@njit(cache=True, nogil=True)
def _drive_output(u: float, eff: np.ndarray) -> float:
    """Saturation and dead zone of the drive (delay is handled by the caller's buffer)."""
    u0 = eff[E.E_DZ_U0]
    if u0 > 0.0:
        u = 0.0 if abs(u) <= u0 else u - math.copysign(u0, u)
    umax = eff[E.E_SAT_UMAX]
    if u > umax:
        u = umax
    elif u < -umax:
        u = -umax
    return u


@njit(cache=True, nogil=True)
def feedforward(
    omega: float,
    alpha: float,
    J: float,
    kv: float,
    kM: float,
    kb: float,
    R: float,
    ku: float,
    tau_c: float,
    tau_s: float,
    v0: float,
) -> float:
    """Voltage that holds speed ω and acceleration α on the nominal model (steady current)."""
    torque = J * alpha + kv * omega
    if omega != 0.0:
        torque += math.copysign(stribeck(omega, tau_c, tau_s, v0), omega)
    return (R * torque / kM + kb * omega) / ku


@njit(cache=True, nogil=True, inline="always")
def ramp_toward(value: float, target: float, step: float) -> float:
    """The scanning speed reference: move toward the target by at most `step`."""
    if value < target:
        return min(value + step, target)
    if value > target:
        return max(value - step, target)
    return value


@njit(cache=True, nogil=True, inline="always")
def track(
    phi: float,
    omega: float,
    phi_ref: float,
    omega_ref: float,
    alpha_ref: float,
    max_lag: float,
    use_ff: bool,
    J: float,
    kv: float,
    kM: float,
    kb: float,
    R: float,
    ku: float,
    tau_c: float,
    tau_s: float,
    v0: float,
    Gp: float,
    Gd: float,
    Gr: float,
    G0: float,
    umax: float,
) -> tuple[float, float, float, bool]:
    """Scanning mode, one controller update: the lag beyond ±max_lag slips the angle reference
    (anti-windup), the model's feedforward joins the robust law, the sum stays within ±umax.
    Returns (u, u_ff, phi_ref after a slip, slipped). Shared by this kernel and the 10 kHz
    control thread, which each integrate the references in their own order."""
    eps = phi_ref - phi
    slipped = eps > max_lag or eps < -max_lag
    if slipped:
        phi_ref = phi + math.copysign(max_lag, eps)
        eps = phi_ref - phi
    u_ff = feedforward(omega_ref, alpha_ref, J, kv, kM, kb, R, ku, tau_c, tau_s, v0) if use_ff else 0.0
    u = robust_law(eps, omega_ref - omega, Gp, Gd, Gr, G0, max(umax - abs(u_ff), 0.0)) + u_ff
    return u, u_ff, phi_ref, slipped


@njit(cache=True, nogil=True, inline="always")
def _derivs(
    omega: float,
    cur: float,
    u_app: float,
    tau_hold: float,
    accel_noise: float,
    inv_J: float,
    kv: float,
    kM: float,
    kb: float,
    R: float,
    inv_L: float,
    ku: float,
    ratio: float,
) -> tuple[float, float]:
    """(ω̇, i̇); `tau_hold` = effect torques − LuGre torque, held over the step.

    Takes 1/J and 1/L: eight divisions per step cost more than the rest of the stage arithmetic.
    """
    level = ratio if omega < 0.0 else 1.0
    domega = (kM * cur - level * kv * omega + tau_hold) * inv_J - accel_noise
    dcur = (-kb * omega - R * cur + ku * u_app) * inv_L
    return domega, dcur


@njit(cache=True, nogil=True)
def run(
    state: np.ndarray,
    plant: np.ndarray,
    eff: np.ndarray,
    vib: np.ndarray,
    ctrl: np.ndarray,
    dt: float,
    n_steps: int,
    u_in: np.ndarray,
    decim: int,
    seed: int,
    out: np.ndarray,
) -> int:
    """Simulate n_steps of dt; write n_steps // decim rows into `out`; update `state` in place.

    The controller (or the open-loop input u_in, one value per controller period) updates every
    ctrl[C_DIV] steps, so the plant can be integrated finer than the loop runs.

    Returns the number of reference slips in scanning mode (the anti-windup of the lag).
    """
    if seed >= 0:
        _seed(seed)
    J0, kv0, kM0, kb0 = plant[P.P_J], plant[P.P_KV], plant[P.P_KM], plant[P.P_KB]
    R0, L, ku = plant[P.P_R], plant[P.P_L], plant[P.P_KU]
    inv_L = 1.0 / L
    tc0, ts0, s0, s1, s2, v0 = (
        plant[P.P_TC],
        plant[P.P_TS],
        plant[P.P_S0],
        plant[P.P_S1],
        plant[P.P_S2],
        plant[P.P_V0],
    )
    ratio = eff[E.E_FRIC_RATIO]
    has_torque = eff[E.E_IMB_AMP] != 0.0 or eff[E.E_COG_AMP] != 0.0 or eff[E.E_RES_AMP] != 0.0
    drift_param = int(eff[E.E_DRIFT_PARAM])
    drift_rel = eff[E.E_DRIFT_REL]
    duration = n_steps * dt

    vib_mode = int(vib[P.V_MODE])
    sigma_v, tau_n = vib[P.V_SIGMA], vib[P.V_TAU]
    if eff[E.E_NOISE_TAU] > 0.0 and vib_mode != 0:
        vib_mode, tau_n = 2, eff[E.E_NOISE_TAU]
    ou_decay = math.exp(-dt / tau_n)
    ou_gain = sigma_v * math.sqrt(1.0 - ou_decay * ou_decay)
    sde_gain = sigma_v * math.sqrt(dt)

    mode = int(ctrl[C_MODE])
    Gp, Gd, Gr, G0, umax = ctrl[C_GP], ctrl[C_GD], ctrl[C_GR], ctrl[C_G0], ctrl[C_UMAX]
    omega_target = 2.0 * math.pi * ctrl[C_REF]
    ramp = 2.0 * math.pi * ctrl[C_ACCEL] * dt * max(int(ctrl[C_DIV]), 1)
    max_lag = ctrl[C_MAXLAG]
    use_ff = ctrl[C_FF] != 0.0
    div = max(int(ctrl[C_DIV]), 1)
    dt_ctrl = dt * div
    ctrl_countdown = 1

    # Transport delay: a ring of past commands (in the state when it has room, so it persists
    # across calls and costs no allocation), read with linear interpolation.
    delay_steps = eff[E.E_DELAY] / dt
    n_ring = int(delay_steps) + 2
    has_room = state.shape[0] >= N_STATE + n_ring
    ring = state[N_STATE : N_STATE + n_ring] if has_room else np.zeros(n_ring)
    whole = int(delay_steps)
    frac = delay_steps - whole
    delayed = n_ring > 2 or frac > 0.0
    pos = int(state[S_RING_POS]) % n_ring
    t0 = state[S_TIME]

    phi, omega, cur, z = state[S_PHI], state[S_OMEGA], state[S_I], state[S_Z]
    accel = state[S_NOISE]
    phi_ref = ctrl[C_REF] if mode == MODE_POSITION else phi
    omega_ref = omega if mode == MODE_SCAN else 0.0
    omega_ref_prev = omega_ref
    slips = 0
    acc_omega = 0.0
    acc_dist = 0.0
    acc_u = 0.0
    row = 0
    countdown = decim  # an integer modulo per step costs more than the law
    u = 0.0
    u_app = 0.0
    for k in range(n_steps):
        t = t0 + k * dt
        # Parameters that drift move linearly over this call's run.
        J, kv, kM, kb, R, tc, ts = J0, kv0, kM0, kb0, R0, tc0, ts0
        if drift_param >= 0:
            f = 1.0 + drift_rel * (k * dt) / duration
            if drift_param == 0:
                kv = kv0 * f
            elif drift_param == 1:
                J = J0 * f
            elif drift_param == 2:
                R = R0 * f
            elif drift_param == 3:
                kM = kM0 * f
                kb = kb0 * f
            else:
                tc = tc0 * f
                ts = ts0 * f

        # Controller (measured state = true state here; the SIL devices add measurement).
        ctrl_countdown -= 1
        if ctrl_countdown == 0:
            ctrl_countdown = div
            if mode == MODE_OPEN:
                u = u_in[k // div]
            elif mode == MODE_POSITION:
                u = robust_law(phi_ref - phi, -omega, Gp, Gd, Gr, G0, umax)
            else:
                omega_ref = ramp_toward(omega_ref, omega_target, ramp)
                alpha_ref = (omega_ref - omega_ref_prev) / dt_ctrl
                u, _, phi_ref, slipped = track(
                    phi, omega, phi_ref, omega_ref, alpha_ref, max_lag, use_ff,
                    J0, kv0 + s2, kM0, kb0, R0, ku, tc0, ts0, v0, Gp, Gd, Gr, G0, umax,
                )  # fmt: skip
                slips += slipped
                omega_ref_prev = omega_ref

        # Drive: delay, then dead zone and saturation.
        if delayed:  # the ring starts at zero: no command before the run
            j = pos + k
            ring[j % n_ring] = u
            u_del = (1.0 - frac) * ring[(j - whole) % n_ring] + frac * ring[(j - whole - 1) % n_ring]
        else:
            u_del = u
        u_app = _drive_output(u_del, eff)

        # Friction: exact bristle step with ω frozen; σ2 joins the viscous term.
        z, tau_f = lugre_step(z, omega, dt, tc, ts, v0, s0, s1, ratio if omega < 0.0 else 1.0)
        kv_total = kv + s2

        # Vibration acceleration held over the step (OU); the SDE increment comes after RK4.
        a_hold = accel if vib_mode == 2 else 0.0
        # Effect torques at the step's midpoint angle: one evaluation per step keeps the step
        # second-order accurate in them (Δφ ≤ 0.016 rad per step at 25 rev/s).
        tau_ext = _shaft_torque(phi + 0.5 * dt * omega, t + 0.5 * dt, eff) if has_torque else 0.0
        tau_hold = tau_ext - tau_f
        h2 = 0.5 * dt
        inv_J = 1.0 / J
        k1w, k1i = _derivs(omega, cur, u_app, tau_hold, a_hold, inv_J, kv_total, kM, kb, R, inv_L, ku, ratio)
        k2w, k2i = _derivs(
            omega + h2 * k1w,
            cur + h2 * k1i,
            u_app,
            tau_hold,
            a_hold,
            inv_J,
            kv_total,
            kM,
            kb,
            R,
            inv_L,
            ku,
            ratio,
        )
        k3w, k3i = _derivs(
            omega + h2 * k2w,
            cur + h2 * k2i,
            u_app,
            tau_hold,
            a_hold,
            inv_J,
            kv_total,
            kM,
            kb,
            R,
            inv_L,
            ku,
            ratio,
        )
        k4w, k4i = _derivs(
            omega + dt * k3w,
            cur + dt * k3i,
            u_app,
            tau_hold,
            a_hold,
            inv_J,
            kv_total,
            kM,
            kb,
            R,
            inv_L,
            ku,
            ratio,
        )
        omega_old = omega
        # φ̇ = ω: RK4's φ stages are the ω stages.
        phi += dt / 6.0 * (omega + 2.0 * (omega + h2 * k1w) + 2.0 * (omega + h2 * k2w) + (omega + dt * k3w))
        omega += dt / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w)
        cur += dt / 6.0 * (k1i + 2.0 * k2i + 2.0 * k3i + k4i)

        # Disturbance acceleration about the SA axis over this step: what the SA IMU measures.
        dist = tau_ext * inv_J
        if vib_mode == 1:
            dw = sde_gain * np.random.standard_normal()
            omega -= dw
            dist -= dw / dt
        elif vib_mode == 2:
            dist -= accel
            accel = accel * ou_decay + ou_gain * np.random.standard_normal()

        if mode == MODE_SCAN:
            phi_ref += omega_ref * dt
        acc_omega += 0.5 * (omega + omega_old)
        acc_dist += dist
        acc_u += u
        countdown -= 1
        if countdown == 0 and row < out.shape[0]:
            countdown = decim
            out[row, O_T] = t0 + (k + 1) * dt
            out[row, O_U] = u
            out[row, O_UAPP] = u_app
            out[row, O_PHI] = phi
            out[row, O_OMEGA] = omega
            out[row, O_I] = cur
            out[row, O_Z] = z
            out[row, O_OMEGA_MEAN] = acc_omega / decim
            out[row, O_DIST_MEAN] = acc_dist / decim
            out[row, O_PHI_REF] = phi_ref
            out[row, O_U_MEAN] = acc_u / decim
            acc_omega = 0.0
            acc_dist = 0.0
            acc_u = 0.0
            row += 1

    state[S_PHI], state[S_OMEGA], state[S_I], state[S_Z], state[S_NOISE] = phi, omega, cur, z, accel
    state[S_TIME] = t0 + n_steps * dt
    state[S_RING_POS] = (pos + n_steps) % n_ring
    return slips
