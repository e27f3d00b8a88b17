"""The scanning-aperture drive, paper eqs. (9)–(11), as numba kernels with the effects library.

    φ̇ = ω
    J·ω̇ = kM·i − kv·ω − τf − J·Δv + τ_effects(φ, t)
    L·i̇ = −kb·ω − R·i + ku·u_applied

Integration (MODEL-NOTES §7): RK4 for (φ, ω, i) with u, τf and the OU acceleration held over the
step; the exact exponential step for the LuGre state z (tvsd.model.lugre); the literal SDE's noise
(eq. 12) as an additive Euler–Maruyama increment after the step. At dt = 1e-4 s this matches a
1e-7 s reference to ≤ 0.3 % in settling time.

The pieces of one step (`drifted`, `delayed`, `drive_output`, `physics_step`) are inlined into
two loops: `advance` here (open loop: the SIL plant behind the control thread and the virtual MCU)
and the closed-loop simulation of tvsd.sim.closed_loop, so both integrate exactly alike.
Neither allocates per step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tvsd.model import effects as E
from tvsd.model import params as P
from tvsd.model.lugre import lugre_step

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
def seed_noise(seed: int) -> None:
    np.random.seed(seed)


@njit(cache=True, nogil=True, inline="always")
def shaft_torque(phi: float, t: float, eff: np.ndarray) -> float:
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
def drive_output(u: float, eff: np.ndarray) -> float:
    """Saturation and dead zone of the drive (delay is handled by the delay ring)."""
    u0 = eff[E.E_DZ_U0]
    if u0 > 0.0:
        u = 0.0 if abs(u) <= u0 else u - math.copysign(u0, u)
    umax = eff[E.E_SAT_UMAX]
    if u > umax:
        u = umax
    elif u < -umax:
        u = -umax
    return u


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


Seven = tuple[float, float, float, float, float, float, float]


@njit(cache=True, nogil=True, inline="always")
def drifting_base(plant: np.ndarray) -> Seven:
    """What a drift effect can move, read once per call: (J, kv, kM, kb, R, τc, τs)."""
    return (
        plant[P.P_J],
        plant[P.P_KV],
        plant[P.P_KM],
        plant[P.P_KB],
        plant[P.P_R],
        plant[P.P_TC],
        plant[P.P_TS],
    )


@njit(cache=True, nogil=True, inline="always")
def fixed_constants(plant: np.ndarray, eff: np.ndarray) -> Seven:
    """What no effect drifts, read once per call: (1/L, ku, v0, σ0, σ1, σ2, friction ratio)."""
    return (
        1.0 / plant[P.P_L],
        plant[P.P_KU],
        plant[P.P_V0],
        plant[P.P_S0],
        plant[P.P_S1],
        plant[P.P_S2],
        eff[E.E_FRIC_RATIO],
    )


@njit(cache=True, nogil=True, inline="always")
def noise_constants(vib: np.ndarray, eff: np.ndarray, dt: float) -> tuple[int, float, float, float]:
    """(mode, OU decay, OU gain, SDE gain) of the vibration Δv; a colored_noise effect makes it OU."""
    vib_mode = int(vib[P.V_MODE])
    sigma_v, tau_n = vib[P.V_SIGMA], vib[P.V_TAU]
    if eff[E.E_NOISE_TAU] > 0.0 and vib_mode != 0:
        vib_mode, tau_n = 2, eff[E.E_NOISE_TAU]
    ou_decay = math.exp(-dt / tau_n)
    ou_gain = sigma_v * math.sqrt(1.0 - ou_decay * ou_decay)
    sde_gain = sigma_v * math.sqrt(dt)
    return vib_mode, ou_decay, ou_gain, sde_gain


@njit(cache=True, nogil=True, inline="always")
def drifted(base: Seven, drift_param: int, drift_rel: float, elapsed: float, duration: float) -> Seven:
    """(J, kv, kM, kb, R, τc, τs) with a drifting parameter moved linearly over the call's run."""
    J, kv, kM, kb, R, tc, ts = base
    if drift_param >= 0:
        f = 1.0 + drift_rel * elapsed / duration
        if drift_param == 0:
            kv = kv * f
        elif drift_param == 1:
            J = J * f
        elif drift_param == 2:
            R = R * f
        elif drift_param == 3:
            kM = kM * f
            kb = kb * f
        else:
            tc = tc * f
            ts = ts * f
    return J, kv, kM, kb, R, tc, ts


@njit(cache=True, nogil=True, inline="always")
def delay_ring(
    state: np.ndarray, eff: np.ndarray, dt: float
) -> tuple[np.ndarray, int, int, float, bool, int]:
    """The transport delay's ring of past commands (in the state when it has room, so it persists
    across calls and costs no allocation): (ring, size, whole steps, fraction, active, position)."""
    delay_steps = eff[E.E_DELAY] / dt
    n_ring = int(delay_steps) + 2
    has_room = state.shape[0] >= N_STATE + n_ring
    ring = state[N_STATE : N_STATE + n_ring] if has_room else np.zeros(n_ring)
    whole = int(delay_steps)
    frac = delay_steps - whole
    return ring, n_ring, whole, frac, n_ring > 2 or frac > 0.0, int(state[S_RING_POS]) % n_ring


@njit(cache=True, nogil=True, inline="always")
def delayed(ring: np.ndarray, n_ring: int, whole: int, frac: float, j: int, u: float) -> float:
    """Push command u at ring index j; the command `delay_s` ago, interpolated between steps.
    The ring starts at zero: no command before the run."""
    ring[j % n_ring] = u
    return (1.0 - frac) * ring[(j - whole) % n_ring] + frac * ring[(j - whole - 1) % n_ring]


@njit(cache=True, nogil=True, inline="always")
def physics_step(
    phi: float,
    omega: float,
    cur: float,
    z: float,
    accel: float,
    t: float,
    dt: float,
    u_app: float,
    J: float,
    kv: float,
    kM: float,
    kb: float,
    R: float,
    tc: float,
    ts: float,
    fixed: Seven,
    eff: np.ndarray,
    has_torque: bool,
    vib_mode: int,
    ou_decay: float,
    ou_gain: float,
    sde_gain: float,
) -> tuple[float, float, float, float, float, float]:
    """One step of dt with the applied voltage u_app: (φ, ω, i, z, OU acceleration, disturbance
    acceleration about the SA axis over the step — what the SA IMU measures)."""
    inv_L, ku, v0, s0, s1, s2, ratio = fixed
    # Friction: exact bristle step with ω frozen; σ2 joins the viscous term.
    z, tau_f = lugre_step(z, omega, dt, tc, ts, v0, s0, s1, ratio if omega < 0.0 else 1.0)
    kv_total = kv + s2

    # Vibration acceleration held over the step (OU); the SDE increment comes after RK4.
    a_hold = accel if vib_mode == 2 else 0.0
    # Effect torques at the step's midpoint angle: one evaluation per step keeps the step
    # second-order accurate in them (Δφ ≤ 0.016 rad per step at 25 rev/s).
    tau_ext = shaft_torque(phi + 0.5 * dt * omega, t + 0.5 * dt, eff) if has_torque else 0.0
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
    # φ̇ = ω: RK4's φ stages are the ω stages.
    phi += dt / 6.0 * (omega + 2.0 * (omega + h2 * k1w) + 2.0 * (omega + h2 * k2w) + (omega + dt * k3w))
    omega += dt / 6.0 * (k1w + 2.0 * k2w + 2.0 * k3w + k4w)
    cur += dt / 6.0 * (k1i + 2.0 * k2i + 2.0 * k3i + k4i)

    dist = tau_ext * inv_J
    if vib_mode == 1:
        dw = sde_gain * np.random.standard_normal()
        omega -= dw
        dist -= dw / dt
    elif vib_mode == 2:
        dist -= accel
        accel = accel * ou_decay + ou_gain * np.random.standard_normal()
    return phi, omega, cur, z, accel, dist


@njit(cache=True, nogil=True)
def advance(
    state: np.ndarray,
    plant: np.ndarray,
    eff: np.ndarray,
    vib: np.ndarray,
    dt: float,
    n_steps: int,
    u_in: np.ndarray,
    u_div: int,
    seed: int,
) -> float:
    """Open loop: n_steps of dt with the command u_in[k // u_div] (one value per u_div steps);
    `state` updated in place. Returns the mean disturbance acceleration over the call (rad/s²).
    A seed ≥ 0 reseeds the vibration first (once per run; per-tick calls pass -1)."""
    if seed >= 0:
        seed_noise(seed)
    has_torque = eff[E.E_IMB_AMP] != 0.0 or eff[E.E_COG_AMP] != 0.0 or eff[E.E_RES_AMP] != 0.0
    drift_param = int(eff[E.E_DRIFT_PARAM])
    drift_rel = eff[E.E_DRIFT_REL]
    duration = n_steps * dt
    vib_mode, ou_decay, ou_gain, sde_gain = noise_constants(vib, eff, dt)
    fixed = fixed_constants(plant, eff)
    base = drifting_base(plant)
    ring, n_ring, whole, frac, has_delay, pos = delay_ring(state, eff, dt)
    t0 = state[S_TIME]
    phi, omega, cur, z = state[S_PHI], state[S_OMEGA], state[S_I], state[S_Z]
    accel = state[S_NOISE]
    acc_dist = 0.0
    for k in range(n_steps):
        J, kv, kM, kb, R, tc, ts = drifted(base, drift_param, drift_rel, k * dt, duration)
        u = u_in[k // u_div]
        u_del = delayed(ring, n_ring, whole, frac, pos + k, u) if has_delay else u
        u_app = drive_output(u_del, eff)
        phi, omega, cur, z, accel, dist = physics_step(
            phi, omega, cur, z, accel, t0 + k * dt, dt, u_app, J, kv, kM, kb, R, tc, ts,
            fixed, eff, has_torque, vib_mode, ou_decay, ou_gain, sde_gain,
        )  # fmt: skip
        acc_dist += dist
    state[S_PHI], state[S_OMEGA], state[S_I], state[S_Z], state[S_NOISE] = phi, omega, cur, z, accel
    state[S_TIME] = t0 + n_steps * dt
    state[S_RING_POS] = (pos + n_steps) % n_ring
    return acc_dist / n_steps if n_steps > 0 else 0.0
