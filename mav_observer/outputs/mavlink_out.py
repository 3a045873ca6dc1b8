"""The estimate sent back over MAVLink: LANDING_TARGET in its position form and STATUSTEXT
(``[mavlink] out = true``, ``run --mavlink-out URL``; ``docs/geolocation.md``).

* **LANDING_TARGET** for each chosen target whose estimate is ``converged``, at most
  ``out_rate_hz`` per target, ``position_valid`` 1:

  - ``out_frame = "local_ned"`` (the default; what PX4 reads): ``frame``
    MAV_FRAME_LOCAL_NED, ``x, y, z`` the target in the autopilot's local frame
    (``target_pos_ned_m``);
  - ``out_frame = "body_frd"`` (what ArduPilot reads: it refuses the local frame):
    ``frame`` MAV_FRAME_BODY_FRD, ``x, y, z`` the target relative to the vehicle in its
    body frame (needs the vehicle's attitude at the estimate's time);

  ``distance`` the range (the norm of the relative position: ArduPilot divides the body
  ``x, y, z`` by it), ``angle_x, angle_y`` the line of sight in the body frame as a downward
  camera reports it (``(-tan angle_y, tan angle_x, 1)`` along it, the convention the tracker
  reads, :func:`mav_observer.tracking.directions.landing_target_direction`; 0 when the target
  is not below the body's x-y plane or the attitude is unknown), ``time_usec`` the
  estimate's time on the autopilot clock (us since boot), ``target_num`` the target's number
  (``landing_target_<n>``: ``n``; otherwise its place in ``out_targets``, or 0), ``type``
  LANDING_TARGET_TYPE_VISION_OTHER, ``q`` identity.
* **STATUSTEXT** (MAV_SEVERITY_INFO) when a target converges, or when its estimate has
  moved by more than its horizontal 1-sigma since the last one sent, and its place on the
  map is known: ``gimbal: -35.36290 149.16556 584m +-0.8m`` (the way ground stations show
  points of interest in their messages).

Sent from system 254, component 191 (an onboard computer; never 255, the ground station's
id), signed when a signing key is set, over the input connection (a companion computer talks
to its autopilot through a router) or to ``out_url``. Building the messages is pure
(:func:`landing_target`, :func:`statustext`); :class:`MavlinkOut` decides when.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mav_observer.geo.frames import euler_to_dcm
from mav_observer.mavlink.dialect import mavlink
from mav_observer.outputs.records import EstimateRecord

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
LANDING_TARGET_TYPE_VISION_OTHER = 3
MAV_SEVERITY_INFO = 6
#: STATUSTEXT's text field holds this many characters.
STATUSTEXT_LEN = 50


@dataclass(frozen=True)
class OutConfig:
    """What is sent back (the ``[mavlink]`` ``out*`` settings)."""

    enabled: bool = False
    url: str | None = None
    targets: tuple[str, ...] = ()
    rate_hz: float = 4.0
    statustext: bool = True
    #: ``"local_ned"`` (PX4 reads this form) or ``"body_frd"`` (ArduPilot's: it refuses
    #: MAV_FRAME_LOCAL_NED)
    frame: str = "local_ned"

    def chosen(self, target: str) -> bool:
        return not self.targets or target in self.targets

    def target_num(self, target: str) -> int:
        if target.startswith("landing_target_") and target[15:].isdigit():
            return int(target[15:])
        return self.targets.index(target) if target in self.targets else 0


def body_angles(
    rel_pos_ned_m: tuple[float, float, float], rpy_rad: tuple[float, float, float] | None
) -> tuple[float, float]:
    """``(angle_x, angle_y)`` (rad) of the line of sight ``rel_pos_ned_m`` in the body frame of
    a vehicle at roll, pitch, yaw ``rpy_rad``, as a downward camera reports them; ``(0, 0)``
    when the attitude is unknown or the target is not below the body's x-y plane."""
    if rpy_rad is None:
        return 0.0, 0.0
    r = euler_to_dcm(*rpy_rad)  # body to NED
    n, e, d = rel_pos_ned_m
    xb = r[0][0] * n + r[1][0] * e + r[2][0] * d
    yb = r[0][1] * n + r[1][1] * e + r[2][1] * d
    zb = r[0][2] * n + r[1][2] * e + r[2][2] * d
    if not zb > 0.0:
        return 0.0, 0.0
    return math.atan2(yb, zb), math.atan2(-xb, zb)


def landing_target(
    rec: EstimateRecord,
    target_num: int,
    rpy_rad: tuple[float, float, float] | None,
    frame: str = "local_ned",
) -> Any:
    """LANDING_TARGET of ``rec`` in its position form (see the module docstring), or ``None``
    without a target position (``frame`` ``"local_ned"``: in the local frame; ``"body_frd"``:
    relative to the vehicle in its body frame, which needs the attitude ``rpy_rad``)."""
    x = rec.estimate.x_m
    rel = (float(x[0]), float(x[1]), float(x[2]))
    if frame == "body_frd":
        if rpy_rad is None or not all(math.isfinite(v) for v in rel):
            return None
        r = euler_to_dcm(*rpy_rad)  # body to NED; its transpose takes NED to body
        pos = tuple(sum(r[i][j] * rel[i] for i in range(3)) for j in range(3))
        mav_frame = MAV_FRAME_BODY_FRD
    else:
        tp = rec.target_pos_ned_m
        if tp is None or not all(math.isfinite(v) for v in tp):
            return None
        pos, mav_frame = tp, MAV_FRAME_LOCAL_NED
    ax, ay = body_angles(rel, rpy_rad)
    return mavlink.MAVLink_landing_target_message(
        max(0, round(rec.t_boot_s * 1e6)),
        target_num,
        mav_frame,
        ax,
        ay,
        math.sqrt(sum(c * c for c in rel)),
        0.0,
        0.0,
        pos[0],
        pos[1],
        pos[2],
        [1.0, 0.0, 0.0, 0.0],
        LANDING_TARGET_TYPE_VISION_OTHER,
        1,
    )


def statustext(rec: EstimateRecord) -> str | None:
    """``"<target>: <lat> <lon> <alt>m +-<h_std>m"`` (at most :data:`STATUSTEXT_LEN`
    characters), or ``None`` without a place on the map."""
    geo = rec.target_geodetic()
    if geo is None or not all(math.isfinite(v) for v in geo[:3]):
        return None
    lat, lon, alt, h_sd, _ = geo
    sd = "" if h_sd is None or not math.isfinite(h_sd) else f" +-{h_sd:.1f}m"
    return f"{rec.target}: {lat:.5f} {lon:.5f} {alt:.0f}m{sd}"[:STATUSTEXT_LEN]


@dataclass
class _Sent:
    next_lt_mono: float = 0.0
    converged: bool = False
    text_at: tuple[float, float, float] | None = None  # target_pos_ned_m of the last text


@dataclass
class MavlinkOut:
    """Decides what to send for each estimate and sends it with ``send`` (a pymavlink message
    in, e.g. :meth:`mav_observer.mavlink.connection.ConnectionReader.send`)."""

    config: OutConfig
    send: Callable[[Any], bool]
    sent: dict[str, int] = field(default_factory=lambda: {"LANDING_TARGET": 0, "STATUSTEXT": 0})
    failed: int = 0
    _state: dict[tuple[int, str], _Sent] = field(default_factory=dict)

    def _send(self, msg: Any, name: str) -> None:
        if self.send(msg):
            self.sent[name] += 1
        else:
            self.failed += 1

    def on_estimate(
        self, rec: EstimateRecord, rpy_rad: tuple[float, float, float] | None, now_mono: float
    ) -> None:
        """``rec`` was made (``now_mono``: monotonic seconds); ``rpy_rad``: the vehicle's
        attitude at its time, if known."""
        cfg = self.config
        if not cfg.enabled or not cfg.chosen(rec.target):
            return
        st = self._state.setdefault((rec.sysid, rec.target), _Sent())
        converged = str(rec.estimate.status) == "converged"
        if converged and now_mono >= st.next_lt_mono:
            msg = landing_target(rec, cfg.target_num(rec.target), rpy_rad, cfg.frame)
            if msg is not None:
                st.next_lt_mono = now_mono + 1.0 / cfg.rate_hz
                self._send(msg, "LANDING_TARGET")
        if cfg.statustext and converged:
            tp = rec.target_pos_ned_m
            geo = rec.target_geodetic()
            moved = False
            if tp is not None and st.text_at is not None and geo is not None:
                h_sd = geo[3] if geo[3] is not None else 0.0
                dn, de = tp[0] - st.text_at[0], tp[1] - st.text_at[1]
                moved = math.hypot(dn, de) > max(h_sd, 0.01)
            if (not st.converged or moved) and tp is not None:
                text = statustext(rec)
                if text is not None:
                    st.text_at = tp
                    self._send(
                        mavlink.MAVLink_statustext_message(MAV_SEVERITY_INFO, text.encode()),
                        "STATUSTEXT",
                    )
        st.converged = converged
