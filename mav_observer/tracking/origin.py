"""Where the vehicle's local frame sits on WGS84, and which frame it is.

The origin comes from the most trusted source the stream gives (GPS_GLOBAL_ORIGIN, then
HOME_POSITION, then GLOBAL_POSITION_INT paired with LOCAL_POSITION_NED at the same
time_boot_ms, averaged); while the autopilot's local frame is not set, the pairs vote on it
(:class:`~mav_observer.geo.geodesy.FrameVote`). ``setting`` is ``TrackerConfig.local_frame``;
``note`` counts an event on the vehicle.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from mav_observer.errors import InvalidSampleError
from mav_observer.geo import geodesy
from mav_observer.geo.frames import Vec3
from mav_observer.tracking.directions import Skip
from mav_observer.tracking.vehicle import Vehicle

log = logging.getLogger("mav_observer.tracking.tracker")

Note = Callable[[Vehicle, str], None]

#: How far (m) a new report of a source may put the origin from the one in use before the
#: origin is taken to have moved: GLOBAL_POSITION_INT and LOCAL_POSITION_NED, two estimates
#: rounded to 1 cm and 1e-7 deg (1.1 cm), disagree by centimetres; an EKF origin reset or a
#: new home moves it by metres.
ORIGIN_MOVED_M = {"GPS_GLOBAL_ORIGIN": 0.05, "HOME_POSITION": 0.05, "GLOBAL_POSITION_INT": 1.0}


def local_frame(veh: Vehicle, setting: str) -> str:
    """The vehicle's local frame: the setting, else as its pairs told it, else WGS84."""
    if setting != "auto":
        return setting
    return veh.local_frame or "wgs84"

def vote_frame(veh: Vehicle, lat_deg: float, lon_deg: float, alt_m: float, ned: Vec3,
               note: Note) -> None:  # fmt: skip
    """One more GLOBAL_POSITION_INT and LOCAL_POSITION_NED pair for the frame's vote: the
    origin placed again on the vote's choice when it changes (a GLOBAL_POSITION_INT origin
    with the mean of its pairs on that frame); once the vote has decided, the event
    ``local_frame_<frame>`` counted and the vote ended."""
    vote = veh.frame_vote
    if vote is None:
        return
    vote.add(lat_deg, lon_deg, alt_m, ned)
    origin = veh.origin
    if origin is None:
        return
    frame, decided = vote.choice(origin.frame)
    if decided:
        veh.local_frame, veh.frame_vote = frame, None
        note(veh, f"local_frame_{frame}")
        log.info("vehicle %d: local frame told by its position pairs: %s", veh.sysid, frame)
    if origin.frame == frame:
        return
    if origin.source == "GLOBAL_POSITION_INT":
        veh.origin_mean = vote.means[frame]
        veh.origin = veh.origin_mean.origin
    elif veh.origin_fix is not None:
        source, lat0, lon0, alt0, ned0 = veh.origin_fix
        veh.origin = geodesy.origin_from(lat0, lon0, alt0, ned0, source, frame)

def pair_global_local(veh: Vehicle, setting: str, note: Note) -> None:
    """GLOBAL_POSITION_INT and LOCAL_POSITION_NED at the same time_boot_ms: the origin,
    unless a better source has given it."""
    g, lp = veh.gpi_ms, veh.lpn_ms
    if g is None or lp is None or g[0] != lp[0]:
        return
    if veh.origin is not None and veh.origin.source != "GLOBAL_POSITION_INT":
        if veh.frame_vote is not None:  # a better source placed it: the pair only votes
            try:
                geodesy.check_geodetic(*g[1], "GLOBAL_POSITION_INT")
            except InvalidSampleError as exc:
                raise Skip("out_of_range", str(exc)) from exc
            vote_frame(veh, *g[1], lp[1], note)
        return
    place_origin(veh, "GLOBAL_POSITION_INT", *g[1], lp[1], setting, note)

def place_origin(
    veh: Vehicle, source: str, lat_deg: float, lon_deg: float, alt_m: float, ned: Vec3,
    setting: str, note: Note,
) -> None:  # fmt: skip
    """A point at ``lat_deg, lon_deg, alt_m`` (AMSL) is at ``ned`` in the local frame:
    the origin, if ``source`` is at least as trusted as the one in use
    (:data:`~mav_observer.geo.geodesy.ORIGIN_SOURCES`) and the origin in use does not already
    put it there (within :data:`ORIGIN_MOVED_M`); a moved origin (an EKF origin reset, a
    new home) is counted as ``origin_changed`` and logged. GLOBAL_POSITION_INT's pairs that
    agree with the origin in use are averaged into it (:class:`~mav_observer.geo.geodesy.
    OriginMean`: each is rounded to 1e-7 deg, about 1 cm)."""
    cur = veh.origin
    rank = geodesy.ORIGIN_SOURCES.index(source)
    if cur is not None:
        cur_rank = geodesy.ORIGIN_SOURCES.index(cur.source)
        if rank > cur_rank:
            return
        if rank == cur_rank:
            try:
                geodesy.check_geodetic(lat_deg, lon_deg, alt_m, source)
            except InvalidSampleError as exc:
                raise Skip("out_of_range", str(exc)) from exc
            lat, lon, alt = geodesy.to_geodetic(cur, ned)
            if (
                geodesy.gap_m((lat, lon, alt), (lat_deg, lon_deg, alt_m))
                <= ORIGIN_MOVED_M[source]
            ):
                mean = veh.origin_mean
                if mean is not None:  # another pair: the mean of them all
                    if veh.frame_vote is not None:  # (the mean in use is among its)
                        vote_frame(veh, lat_deg, lon_deg, alt_m, ned, note)
                    else:
                        mean.add(lat_deg, lon_deg, alt_m, ned)
                    veh.origin = veh.origin_mean.origin  # type: ignore[union-attr]
                return
    try:
        origin = geodesy.origin_from(
            lat_deg, lon_deg, alt_m, ned, source, local_frame(veh, setting)
        )
    except InvalidSampleError as exc:
        raise Skip("out_of_range", str(exc)) from exc
    veh.origin = origin
    veh.origin_fix = (source, lat_deg, lon_deg, alt_m, ned)
    vote = None
    if setting == "auto" and veh.local_frame is None:
        vote = geodesy.FrameVote.start(lat_deg, lon_deg, alt_m, ned, source)
    veh.frame_vote = vote
    if source != "GLOBAL_POSITION_INT":
        veh.origin_mean = None
    else:  # the pairs' mean (while the frame is voted on, the vote's for the frame in use)
        veh.origin_mean = vote.means[origin.frame] if vote else geodesy.OriginMean(origin)
    moved = (
        cur is not None
        and geodesy.gap_m(
            (cur.lat_deg, cur.lon_deg, cur.alt_m),
            (origin.lat_deg, origin.lon_deg, origin.alt_m),
        )
        > ORIGIN_MOVED_M[source]
    )
    if moved:
        note(veh, "origin_changed")
    log.info(
        "vehicle %d: local frame origin %s from %s: %.7f %.7f %.2f m",
        veh.sysid,
        "found" if cur is None else ("moved" if moved else "confirmed"),
        source,
        origin.lat_deg,
        origin.lon_deg,
        origin.alt_m,
    )
