"""How far the shared SITL log's servo mount points from its region of interest, and what the
best offline fit makes of those bearings.

``python -m bench.accuracy.sitl_pointing``

``ardupilot_sitl_servo_mount_roi.tlog``'s gimbal is told to point at a region of interest (ROI,
40 m north and 30 m east of home, on the ground). Its bearings (GIMBAL_DEVICE_ATTITUDE_STATUS
read both ways, the vehicle attitude from ATTITUDE interpolated to the gimbal's time) are
compared with the line of sight from LOCAL_POSITION_NED to the ROI: the angle between them
(deg) from the time the gimbal turns to the ROI (55 s). Then the batch least-squares fit
(:func:`mav_observer.core.batch_fit.fit_batch`, ``x0`` and a constant ``a``, covariance scaled by
the residuals) over windows of the log: its horizontal distance from the ROI and its own
1-sigma. The gap between the two says how correlated the pointing errors are.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from pymavlink import mavutil

from mav_observer.core import batch_fit as batch
from mav_observer.geo.frames import euler_to_dcm, quat_to_dcm, rot_z
from sim.tlogs import find_tlogs

LOG = "ardupilot_sitl_servo_mount_roi.tlog"
ROI_NED_M = np.array([40.0, 30.0, 0.0])
WINDOWS_S = ((55.0, 100.0), (100.0, 140.0), (140.0, 178.0), (100.0, 178.0), (55.0, 205.0))


def read(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LOCAL_POSITION_NED ``(t, x, y, z, vx, vy, vz)``, ATTITUDE ``(t, roll, pitch, yaw
    unwrapped)`` and the gimbal's ``(t, q)`` rows."""
    m = mavutil.mavlink_connection(path)
    lpn, att, gim = [], [], []
    while (msg := m.recv_match()) is not None:
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            lpn.append((msg.time_boot_ms / 1e3, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
        elif kind == "ATTITUDE":
            att.append((msg.time_boot_ms / 1e3, msg.roll, msg.pitch, msg.yaw))
        elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            gim.append((msg.time_boot_ms / 1e3, *msg.q))
    lp, at, gi = np.array(lpn), np.array(att), np.array(gim)
    lp = lp[np.unique(lp[:, 0], return_index=True)[1]]
    at[:, 3] = np.unwrap(at[:, 3])
    return lp, at, gi


def bearings(lpn: np.ndarray, att: np.ndarray, gim: np.ndarray, reading: str):
    """The gimbal's boresights in NED read as ``"body"`` or ``"flags"`` angles, at the
    gimbal's times inside the position stream."""
    t_out, y_out = [], []
    for row in gim:
        t = row[0]
        if not lpn[0, 0] < t < lpn[-1, 0] or t in t_out[-1:]:
            continue
        r, p, yaw = (float(np.interp(t, att[:, 0], att[:, i])) for i in (1, 2, 3))
        frame = np.array(euler_to_dcm(r, p, yaw) if reading == "body" else rot_z(yaw))
        y_out.append(frame @ np.array(quat_to_dcm(tuple(row[1:5])))[:, 0])
        t_out.append(t)
    return np.array(t_out), np.array(y_out)


def main() -> int:
    lpn, att, gim = read(str(find_tlogs() / LOG))
    print("| reading | pointing error from 55 s: median | 90 % | 99 % | max |")
    print("|---|---|---|---|---|")
    fits = []
    for reading in ("body", "flags"):
        t, y = bearings(lpn, att, gim, reading)
        pos = np.column_stack([np.interp(t, lpn[:, 0], lpn[:, i]) for i in (1, 2, 3)])
        los = ROI_NED_M - pos
        los /= np.linalg.norm(los, axis=1)[:, None]
        err = np.degrees(np.arccos(np.clip(np.sum(los * y, axis=1), -1.0, 1.0)))[t >= 55.0]
        q = np.percentile(err, [50, 90, 99, 100])
        print(f"| {reading} | {q[0]:.2f} deg | {q[1]:.2f} deg | {q[2]:.2f} deg | {q[3]:.2f} deg |")
        for w0, w1 in WINDOWS_S:
            s = (t >= w0) & (t <= w1)
            d = batch.displacement_at(t[s], lpn[:, 0], lpn[:, 4:7], lpn[:, 1:4])
            fit = batch.fit_batch(
                t[s], y[s], d, sigma_rad=math.radians(0.5), covariance_from="residuals"
            )
            p0 = np.array([np.interp(t[s][0], lpn[:, 0], lpn[:, i]) for i in (1, 2, 3)])
            e = fit.x0_ned_m + p0 - ROI_NED_M
            sd = float(np.hypot(*np.sqrt(np.diag(fit.covariance)[:2])))
            fits.append((reading, w0, w1, float(np.hypot(e[0], e[1])), sd))
    print()
    print("| reading | window (s) | batch fit: horizontal error | its 1-sigma (residuals) |")
    print("|---|---|---|---|")
    for reading, w0, w1, h, sd in fits:
        print(f"| {reading} | {w0:.0f}-{w1:.0f} | {h:.2f} m | {sd:.2f} m |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
