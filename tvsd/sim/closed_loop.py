"""The offline simulation of one run: the drive model (tvsd.model.plant) under the robust law in
position or scanning mode, or open loop with a given command, as one numba kernel.

Scanning mode adds the model's feedforward voltage when asked, so the law only corrects around it
(tvsd.control.scanning). The kernel writes decimated rows into a preallocated output array and
allocates nothing per step. The plant is integrated by the same inlined step as the SIL plant's
open-loop `advance`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tvsd.control import layout as W
from tvsd.control.law import robust_law
from tvsd.control.scanning import ramp_toward, track
from tvsd.model import effects as E
from tvsd.model import params as P
from tvsd.model import plant as K

# The controller array: the law's words (tvsd.control.layout; mode MODE_OFF here is open loop, u
# from the input array), then C_DIV: plant steps per controller update (the law and u_in update
# every C_DIV steps).
C_DIV = W.N_LAW
N_CTRL = W.N_LAW + 1
MODE_OPEN, MODE_POSITION, MODE_SCAN = W.MODE_OFF, W.MODE_POSITION, W.MODE_SCAN

# Output columns (one row every `decim` steps).
O_T, O_U, O_UAPP, O_PHI, O_OMEGA, O_I, O_Z, O_OMEGA_MEAN, O_DIST_MEAN, O_PHI_REF, O_U_MEAN = range(11)
N_OUT = 11


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
    exc: np.ndarray,
    decim: int,
    seed: int,
    out: np.ndarray,
) -> int:
    """Simulate n_steps of dt; write n_steps // decim rows into `out`; update `state` in place.

    The controller (or the open-loop input u_in, one value per controller period) updates every
    ctrl[C_DIV] steps, so the plant can be integrated finer than the loop runs.
    In scanning mode, row j of `exc` (rows × 2: rev/s added to the speed target, volts added to
    the law's output, then clipped to ±umax) holds for controller period j, as the control thread
    plays `tvsctl identify`'s table; past its last row (or with 0 rows) nothing is added.

    Returns the number of reference slips in scanning mode (the anti-windup of the lag).
    """
    if seed >= 0:
        K.seed_noise(seed)
    J0, kv0, kM0, kb0 = plant[P.P_J], plant[P.P_KV], plant[P.P_KM], plant[P.P_KB]
    R0, ku = plant[P.P_R], plant[P.P_KU]
    tc0, ts0, s2, v0 = plant[P.P_TC], plant[P.P_TS], plant[P.P_S2], plant[P.P_V0]
    has_torque = eff[E.E_IMB_AMP] != 0.0 or eff[E.E_COG_AMP] != 0.0 or eff[E.E_RES_AMP] != 0.0
    drift_param = int(eff[E.E_DRIFT_PARAM])
    drift_rel = eff[E.E_DRIFT_REL]
    duration = n_steps * dt
    vib_mode, ou_decay, ou_gain, sde_gain = K.noise_constants(vib, eff, dt)
    fixed = K.fixed_constants(plant, eff)
    base = K.drifting_base(plant)

    mode = int(ctrl[W.MODE])
    Gp, Gd, Gr, G0, umax = ctrl[W.GP], ctrl[W.GD], ctrl[W.GR], ctrl[W.G0], ctrl[W.UMAX]
    omega_target = 2.0 * math.pi * ctrl[W.REF]
    ramp = 2.0 * math.pi * ctrl[W.ACCEL] * dt * max(int(ctrl[C_DIV]), 1)
    max_lag = ctrl[W.MAXLAG]
    use_ff = ctrl[W.FF] != 0.0
    div = max(int(ctrl[C_DIV]), 1)
    dt_ctrl = dt * div
    ctrl_countdown = 1

    ring, n_ring, whole, frac, has_delay, pos = K.delay_ring(state, eff, dt)
    t0 = state[K.S_TIME]

    phi, omega, cur, z = state[K.S_PHI], state[K.S_OMEGA], state[K.S_I], state[K.S_Z]
    accel = state[K.S_NOISE]
    phi_ref = ctrl[W.REF] if mode == MODE_POSITION else phi
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
        J, kv, kM, kb, R, tc, ts = K.drifted(base, drift_param, drift_rel, k * dt, duration)

        # Controller (measured state = true state here; the SIL devices add measurement).
        ctrl_countdown -= 1
        if ctrl_countdown == 0:
            ctrl_countdown = div
            if mode == MODE_OPEN:
                u = u_in[k // div]
            elif mode == MODE_POSITION:
                u = robust_law(phi_ref - phi, -omega, Gp, Gd, Gr, G0, umax)
            else:
                j = k // div
                d_rps, d_u = (exc[j, 0], exc[j, 1]) if j < exc.shape[0] else (0.0, 0.0)
                omega_ref = ramp_toward(omega_ref, omega_target + 2.0 * math.pi * d_rps, ramp)
                alpha_ref = (omega_ref - omega_ref_prev) / dt_ctrl
                u, _, phi_ref, slipped = track(
                    phi, omega, phi_ref, omega_ref, alpha_ref, max_lag, use_ff,
                    J0, kv0 + s2, kM0, kb0, R0, ku, tc0, ts0, v0, Gp, Gd, Gr, G0, umax,
                )  # fmt: skip
                u = min(max(u + d_u, -umax), umax)
                slips += slipped
                omega_ref_prev = omega_ref

        # Drive: delay, then dead zone and saturation.
        u_del = K.delayed(ring, n_ring, whole, frac, pos + k, u) if has_delay else u
        u_app = K.drive_output(u_del, eff)
        omega_old = omega
        phi, omega, cur, z, accel, dist = K.physics_step(
            phi, omega, cur, z, accel, t, dt, u_app, J, kv, kM, kb, R, tc, ts,
            fixed, eff, has_torque, vib_mode, ou_decay, ou_gain, sde_gain,
        )  # fmt: skip

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

    state[K.S_PHI], state[K.S_OMEGA], state[K.S_I], state[K.S_Z], state[K.S_NOISE] = phi, omega, cur, z, accel
    state[K.S_TIME] = t0 + n_steps * dt
    state[K.S_RING_POS] = (pos + n_steps) % n_ring
    return slips
