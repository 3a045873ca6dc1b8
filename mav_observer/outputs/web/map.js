// The live map and the replay report: the estimates of mav-observer on a Leaflet map, in the
// local NED frame (a metric grid, offline) or on a tile layer when one is set and the origin
// is known. Live: /state then /events (server-sent events). Report: window.REPORT and a slider.
// Each vehicle's local frame has its own origin: the first origin known is the map's, and a
// vehicle's positions are drawn shifted by its origin's offset from it (a fleet on one map).
(function () {
  "use strict";
  var CFG = window.MAP_CONFIG || {};
  var REPORT = window.REPORT || null;
  var R_EARTH = 6378137.0, E2 = 6.69437999014e-3;  // WGS84
  var origin = null;
  var mode = "local";
  var map, gridLayer;
  var vehicles = {};
  var targets = {};
  var fused = {};
  var origins = {}, shifts = {};  // a vehicle's origin, its offset (m, north and east) on the map
  var refSysid = null;  // the vehicle whose origin was known first: the local map's frame is its
  var MOVE_M = 0.05;  // an origin that moved less than this (an average refined) moves nothing
  var pending = {};
  var waiting = {};
  var scheduled = false;
  var lastApply = 0;
  var countAt = 0, countStale = false, latencyMedian = null;
  var latencies = [];
  var events = 0;
  var fitted = false;
  // the live page redraws at most this often, on a canvas (the report, static, in SVG): a
  // browser beside the service takes little of its CPU
  var REDRAW_MS = 100;
  // a track or an estimate's history gains a point at most this often (s of the autopilot's
  // clock) and keeps this many: a page left open for hours stays as light as in its first minute
  var TRACK_STEP_S = 1.0;
  var TRACK_POINTS = 600;
  var RING_POINTS = 32;
  // a row's text is rewritten at most every TEXT_MS (its data attributes at every batch), the
  // map drawn at most every MAP_MS, a target on it only when it moved or its ellipse changed
  // by a pixel: 100 targets at 10 Hz would otherwise keep a browser's core a third busy
  var TEXT_MS = 500;
  var MAP_MS = 200;
  var mapTimer = null, mapAt = 0, heldVehicles = {};
  var ppm = 1.0;  // screen pixels per metre at the map's zoom, set at each redraw
  var textTimer = null;

  function toLL(n, e) {
    if (mode === "tiles") { return [origin.lat + n / origin.kn, origin.lon + e / origin.ke]; }
    return [n, e];
  }

  // metres per degree of latitude and of longitude at a latitude, on the WGS84 ellipsoid
  function metresPerDeg(latDeg) {
    var s = Math.sin(latDeg * Math.PI / 180), w = 1 - E2 * s * s;
    return [R_EARTH * (1 - E2) / Math.pow(w, 1.5) * Math.PI / 180,
            R_EARTH / Math.sqrt(w) * Math.cos(latDeg * Math.PI / 180) * Math.PI / 180];
  }

  function ring(n, e, sn, se, k) {
    var pts = [];
    for (var i = 0; i < RING_POINTS; i++) {
      var a = 2 * Math.PI * i / RING_POINTS;
      pts.push(toLL(n + k * sn * Math.cos(a), e + k * se * Math.sin(a)));
    }
    return pts;
  }

  // add a point to a live track when TRACK_STEP_S has passed since its last one, dropping
  // the oldest beyond TRACK_POINTS; ``owner.lastT`` keeps the time of the last point
  function extend(owner, line, ll, t) {
    if (owner.lastT !== undefined && t !== undefined && t - owner.lastT < TRACK_STEP_S &&
        t >= owner.lastT) { return; }
    owner.lastT = t;
    var pts = line.getLatLngs();
    if (pts.length >= TRACK_POINTS) { line.setLatLngs(pts.slice(pts.length - TRACK_POINTS + 1).concat([ll])); }
    else { line.addLatLng(ll); }
  }

  function niceStep(span) {
    var raw = span / 8, p = Math.pow(10, Math.floor(Math.log10(raw)));
    var steps = [1, 2, 5, 10];
    for (var i = 0; i < steps.length; i++) { if (steps[i] * p >= raw) { return steps[i] * p; } }
    return 10 * p;
  }

  function drawGrid() {
    if (mode !== "local") { return; }
    gridLayer.clearLayers();
    var b = map.getBounds();
    var s = niceStep(Math.max(b.getNorth() - b.getSouth(), b.getEast() - b.getWest()));
    for (var n = Math.floor(b.getSouth() / s) * s; n <= b.getNorth(); n += s) {
      L.polyline([[n, b.getWest()], [n, b.getEast()]],
                 {color: n === 0 ? "#999" : "#ddd", weight: 1, interactive: false}).addTo(gridLayer);
      L.marker([n, b.getWest()], {icon: L.divIcon({className: "grid-label", html: "N " + n + " m",
                                                    iconSize: [80, 12], iconAnchor: [-3, 12]}),
                                  interactive: false}).addTo(gridLayer);
    }
    for (var e = Math.floor(b.getWest() / s) * s; e <= b.getEast(); e += s) {
      L.polyline([[b.getSouth(), e], [b.getNorth(), e]],
                 {color: e === 0 ? "#999" : "#ddd", weight: 1, interactive: false}).addTo(gridLayer);
      L.marker([b.getSouth(), e], {icon: L.divIcon({className: "grid-label", html: "E " + e + " m",
                                                     iconSize: [80, 12], iconAnchor: [-3, 14]}),
                                   interactive: false}).addTo(gridLayer);
    }
  }

  function init() {
    var useTiles = CFG.tiles && origin;
    mode = useTiles ? "tiles" : "local";
    map = L.map("map", {preferCanvas: !REPORT, crs: useTiles ? L.CRS.EPSG3857 : L.CRS.Simple, zoomSnap: 0.25,
                        minZoom: useTiles ? 2 : -6, maxZoom: useTiles ? 22 : 8});
    if (useTiles) {
      L.tileLayer(CFG.tiles, {maxZoom: 22}).addTo(map);
      map.setView([origin.lat, origin.lon], 18);
    } else {
      map.setView([0, 0], 1);
    }
    gridLayer = L.layerGroup().addTo(map);
    map.on("moveend zoomend", drawGrid);
    map.on("zoomend", function () { for (var k in targets) { targets[k].drawn = null; } });
    drawGrid();
  }

  function setOrigin(o) {
    if (!o || origin) { return; }
    var k = metresPerDeg(o.lat_deg);
    origin = {lat: o.lat_deg, lon: o.lon_deg, alt: o.alt_m, kn: k[0], ke: k[1]};
    var el = document.getElementById("origin");
    if (el) {
      el.textContent = "origin: " + origin.lat.toFixed(7) + ", " + origin.lon.toFixed(7) +
        (o.source ? " (" + o.source + ")" : "") + "; north up, metres from this origin";
    }
  }

  // north and east (m) of a latitude and longitude from the map's origin (the plane tangent at
  // the origin: a few centimetres off a kilometre away)
  function geoNE(lat, lon) { return [(lat - origin.lat) * origin.kn, (lon - origin.lon) * origin.ke]; }

  // a vehicle's origin: the service's, else the one its estimates imply (a record's target on
  // WGS84 and in the local frame: ``mav-observer map`` gets no origin)
  function noteOrigin(sysid, o, rec) {
    if (!o && !origins[sysid] && rec && rec.target_lat_deg != null && rec.target_pos_ned_m) {
      var tp = rec.target_pos_ned_m, k = metresPerDeg(rec.target_lat_deg);
      o = {lat_deg: rec.target_lat_deg - tp[0] / k[0], lon_deg: rec.target_lon_deg - tp[1] / k[1],
           alt_m: null, source: "its estimates"};
    }
    if (!o || o.lat_deg == null) { return; }
    sysid = String(sysid);
    var had = origins[sysid];
    if (had && had.lat === o.lat_deg && had.lon === o.lon_deg) { return; }
    if (!origin) { setOrigin(o); refSysid = sysid; }
    if (sysid === refSysid && mode !== "tiles") {
      // the local map's frame is this vehicle's: the map's origin follows its origin
      var d = geoNE(o.lat_deg, o.lon_deg);
      if (had && Math.abs(d[0]) < MOVE_M && Math.abs(d[1]) < MOVE_M) { return; }
      origins[sysid] = {lat: o.lat_deg, lon: o.lon_deg};
      if (had) { moveOrigin(o, d); }
      return;
    }
    var before = shiftOf(sysid), after = geoNE(o.lat_deg, o.lon_deg);
    if (had && Math.abs(after[0] - before[0]) < MOVE_M && Math.abs(after[1] - before[1]) < MOVE_M) { return; }
    origins[sysid] = {lat: o.lat_deg, lon: o.lon_deg};
    shifts[sysid] = after;
    if (map) { moveVehicle(sysid, after[0] - before[0], after[1] - before[1]); }
  }

  // the reference vehicle's origin moved by ``d`` (m): the others and the fused targets, placed
  // from it, move the other way
  function moveOrigin(o, d) {
    origin = null;
    setOrigin(o);
    for (var v in shifts) {
      if (v === refSysid) { continue; }
      shifts[v] = [shifts[v][0] - d[0], shifts[v][1] - d[1]];
      if (map) { moveVehicle(v, -d[0], -d[1]); }
    }
    for (var name in fused) {
      var f = fused[name];
      if (!f.layers || !map) { continue; }
      moveLayers([f.layers.hist], -d[0], -d[1]);
      drawFused(f, f.rec, null);
      writeRow(f, f.rec, Date.now());
    }
  }

  function shiftOf(sysid) { return shifts[sysid] || [0, 0]; }

  // a vehicle's local north and east on the map
  function vLL(sysid, n, e) {
    var s = shifts[sysid];
    return s ? toLL(n + s[0], e + s[1]) : toLL(n, e);
  }

  // what a vehicle drew before its origin was known (or before it moved) moves with it
  function moveVehicle(sysid, dn, de) {
    var v = vehicles[sysid], layers = v ? [v.track, v.marker, v.heading] : [], mine = [];
    for (var k in targets) {
      if (targets[k].sysid === String(sysid)) { mine.push(targets[k]); layers.push(targets[k].hist); }
    }
    moveLayers(layers, dn, de);
    mine.forEach(function (t) {  // its latest estimate drawn and written again, where it now is
      if (!t.rec || !t.rec.target_pos_ned_m) { return; }
      drawTarget(t, t.rec.target_pos_ned_m, t.rec.rel_pos_std_ned_m);
      writeRow(t, t.rec, Date.now());
    });
  }

  function moveLayers(layers, dn, de) {
    if (!dn && !de) { return; }
    var f = mode === "tiles" ? [1 / origin.kn, 1 / origin.ke] : [1, 1];
    function mv(p) { return L.latLng(p.lat + dn * f[0], p.lng + de * f[1]); }
    layers.forEach(function (ly) {
      if (!ly.getLatLngs) { ly.setLatLng(mv(ly.getLatLng())); return; }
      var pts = ly.getLatLngs();
      ly.setLatLngs((pts.length && Array.isArray(pts[0]) ? pts[0] : pts).map(mv));
    });
  }

  // a vehicle's colour (its track, its marker, how its targets' estimates moved), by system id;
  // the estimates themselves red, fused targets green
  var COLOURS = ["#0969da", "#8250df", "#bf3989", "#953800", "#1b7c83", "#6e7781", "#4d2d00",
                 "#0550ae", "#a475f9", "#e16f24"];
  function colour(sysid) {
    var i = parseInt(sysid, 10), n = COLOURS.length;
    return isNaN(i) ? COLOURS[0] : COLOURS[((i - 1) % n + n) % n];
  }

  function vehicle(sysid) {
    var v = vehicles[sysid];
    if (!v) {
      v = vehicles[sysid] = {
        track: L.polyline([], {color: colour(sysid), weight: 2, opacity: 0.6}).addTo(map),
        marker: L.circleMarker([0, 0], {radius: 6, color: colour(sysid), fillOpacity: 0.9}).addTo(map),
        heading: L.polyline([], {color: colour(sysid), weight: 3}).addTo(map)
      };
      v.marker.bindTooltip("vehicle " + sysid);
    }
    return v;
  }

  function target(key) {
    var t = targets[key];
    if (!t) {
      t = targets[key] = {
        hist: L.polyline([], {color: colour(key.split("/")[0]), weight: 1, opacity: 0.7}).addTo(map),
        e2: L.polygon([], {color: "#cf222e", weight: 1, fillOpacity: 0.08}).addTo(map),
        e1: L.polygon([], {color: "#cf222e", weight: 2, fillOpacity: 0.15}).addTo(map),
        marker: L.circleMarker([0, 0], {radius: 5, color: "#cf222e", fillOpacity: 1}).addTo(map),
        row: addRow(key, key), sysid: key.split("/")[0], cells: targetCells
      };
      t.marker.bindTooltip(key);
    }
    return t;
  }

  function addRow(key, label) {
    var tr = document.createElement("tr");
    tr.setAttribute("data-key", key);
    tr.innerHTML = "<td></td><td class='st'></td><td class='rg'></td>" +
      "<td class='ne'></td><td class='sd'></td><td class='age muted'></td>";
    tr.firstChild.textContent = label;
    document.querySelector("#targets tbody").appendChild(tr);
    return tr;
  }

  function showVehicle(sysid, pos, yawDeg, track, t) {
    var v = vehicle(sysid);
    if (!pos) { return; }
    v.marker.setLatLng(vLL(sysid, pos[0], pos[1]));
    if (track) { v.track.setLatLngs(track.map(function (p) { return vLL(sysid, p[0], p[1]); })); }
    else { extend(v, v.track, vLL(sysid, pos[0], pos[1]), t); }
    if (yawDeg !== null && yawDeg !== undefined) {
      var y = yawDeg * Math.PI / 180, len = 5;
      v.heading.setLatLngs([vLL(sysid, pos[0], pos[1]),
                            vLL(sysid, pos[0] + len * Math.cos(y), pos[1] + len * Math.sin(y))]);
    }
  }

  // a row's text now, or, for an estimate of the same status less than TEXT_MS after the text
  // was last written, once TEXT_MS has passed
  function showText(entry, rec, history, now) {
    if (history || rec.status !== entry.status || !(now - entry.textAt < TEXT_MS)) {
      writeRow(entry, rec, now);
    } else {
      entry.stale = rec;
      if (!textTimer) { textTimer = setTimeout(flushText, TEXT_MS); }
    }
  }

  function writeRow(entry, rec, now) {
    var st = entry.row.querySelector(".st");
    entry.textAt = now;
    entry.status = rec.status;
    entry.stale = null;
    st.textContent = rec.status;
    st.className = "st " + String(rec.status).replace(/ /g, "_");
    entry.cells(entry, rec);
  }

  function targetCells(t, rec) {
    var tp = rec.target_pos_ned_m, sd = rec.rel_pos_std_ned_m;
    t.row.querySelector(".rg").textContent = rec.range_m.toFixed(2) + " m";
    t.row.querySelector(".age").textContent = "t " + rec.t_boot_s.toFixed(1) + " s";
    if (tp) {  // from the map's origin: every vehicle's targets comparable
      var sh = shiftOf(t.sysid);
      t.row.querySelector(".ne").textContent = (tp[0] + sh[0]).toFixed(2) + ", " + (tp[1] + sh[1]).toFixed(2);
    }
    if (tp && sd) { t.row.querySelector(".sd").textContent = sd[0].toFixed(2) + ", " + sd[1].toFixed(2); }
  }

  // a row's text (or the page's counts) held back is written once TEXT_MS has passed, should no newer estimate come
  function flushText() {
    textTimer = null;
    var now = Date.now();
    for (var k in targets) { if (targets[k].stale) { writeRow(targets[k], targets[k].stale, now); } }
    for (var name in fused) { if (fused[name].stale) { writeRow(fused[name], fused[name].stale, now); } }
    if (countStale) { writeCounts(now); }
  }

  // the live map is drawn at most every MAP_MS, all its changes at once: a canvas that changes
  // costs a browser a copy of it at each frame, whatever changed on it
  function scheduleMap() {
    if (!mapTimer) { mapTimer = setTimeout(flushMap, Math.max(0, mapAt + MAP_MS - Date.now())); }
  }

  function flushMap() {
    mapTimer = null;
    mapAt = Date.now();
    ppm = metrePixels();
    for (var sysid in heldVehicles) {
      var lv = heldVehicles[sysid];
      showVehicle(sysid, lv.record.vehicle_pos_ned_m, lv.yaw_deg, null, lv.record.t_boot_s);
    }
    heldVehicles = {};
    for (var k in targets) {
      var t = targets[k], rec = t.held;
      if (!rec) { continue; }
      t.held = null;
      var tp = rec.target_pos_ned_m, sd = rec.rel_pos_std_ned_m;
      extend(t, t.hist, vLL(t.sysid, tp[0], tp[1]), rec.t_boot_s);
      var sn = sd ? sd[0] : 0, se = sd ? sd[1] : 0, d = t.drawn;
      if (d && ppm * Math.max(Math.abs(tp[0] - d[0]), Math.abs(tp[1] - d[1]),
                              Math.abs(sn - d[2]), Math.abs(se - d[3])) < 1.0) {
        continue;  // not a pixel's change on the map
      }
      drawTarget(t, tp, sd);
    }
    for (var name in fused) {
      var f = fused[name];
      if (f.held) { drawFused(f, f.held, null); f.held = null; }
    }
  }

  function drawTarget(t, tp, sd) {
    t.drawn = [tp[0], tp[1], sd ? sd[0] : 0, sd ? sd[1] : 0];
    var s = shiftOf(t.sysid), n = tp[0] + s[0], e = tp[1] + s[1];
    t.row.setAttribute("data-map-ne", n.toFixed(3) + "," + e.toFixed(3));
    t.marker.setLatLng(toLL(n, e));
    if (sd) {
      t.e1.setLatLngs(ring(n, e, sd[0], sd[1], 1));
      t.e2.setLatLngs(ring(n, e, sd[0], sd[1], 2));
    }
  }

  // an ellipse of k sigma from a north-east covariance (m^2), its axes where they point
  function covRing(n, e, cnn, cne, cee, k) {
    var th = 0.5 * Math.atan2(2 * cne, cnn - cee), m = (cnn + cee) / 2;
    var r = Math.sqrt(Math.max(0, (cnn - cee) * (cnn - cee) / 4 + cne * cne));
    var a = Math.sqrt(Math.max(0, m + r)), b = Math.sqrt(Math.max(0, m - r)), pts = [];
    for (var i = 0; i < RING_POINTS; i++) {
      var u = k * a * Math.cos(2 * Math.PI * i / RING_POINTS), w = k * b * Math.sin(2 * Math.PI * i / RING_POINTS);
      pts.push(toLL(n + u * Math.cos(th) - w * Math.sin(th), e + u * Math.sin(th) + w * Math.cos(th)));
    }
    return pts;
  }

  // a target several vehicles see, fused (``mav-observer fuse``): on WGS84, so on the map once
  // the map's origin is known
  function fusedEntry(name) {
    var f = fused[name];
    if (!f) {
      f = fused[name] = {row: addRow("fused/" + name, "fused: " + name), layers: null, cells: fusedCells};
    }
    return f;
  }

  function drawFused(f, rec, history) {
    if (rec.lat_deg == null || !origin) { return; }
    if (!f.layers) {
      f.layers = {
        hist: L.polyline([], {color: "#1a7f37", weight: 1, opacity: 0.7}).addTo(map),
        e2: L.polygon([], {color: "#1a7f37", weight: 1, fillOpacity: 0.08}).addTo(map),
        e1: L.polygon([], {color: "#1a7f37", weight: 2, fillOpacity: 0.15}).addTo(map),
        marker: L.circleMarker([0, 0], {radius: 7, color: "#1a7f37", fillOpacity: 1}).addTo(map)
      };
      f.layers.marker.bindTooltip(f.row.firstChild.textContent);
    }
    var ly = f.layers, ne = geoNE(rec.lat_deg, rec.lon_deg), c = rec.cov_ned_m2;
    f.row.setAttribute("data-map-ne", ne[0].toFixed(3) + "," + ne[1].toFixed(3));
    if (history) {
      ly.hist.setLatLngs(history.map(function (p) { var q = geoNE(p[0], p[1]); return toLL(q[0], q[1]); }));
    } else { extend(f, ly.hist, toLL(ne[0], ne[1]), rec.t_unix_s); }
    ly.marker.setLatLng(toLL(ne[0], ne[1]));
    if (c) {
      ly.e1.setLatLngs(covRing(ne[0], ne[1], c[0][0], c[0][1], c[1][1], 1));
      ly.e2.setLatLngs(covRing(ne[0], ne[1], c[0][0], c[0][1], c[1][1], 2));
    }
    if (!fitted) {
      fitted = true;
      map.fitBounds(L.latLngBounds([toLL(ne[0] - 50, ne[1] - 50), toLL(ne[0] + 50, ne[1] + 50)]));
    }
  }

  function showFused(name, rec, history) {
    var f = fusedEntry(name), now = Date.now();
    f.rec = rec;
    f.row.setAttribute("data-status", rec.status);
    f.row.setAttribute("data-t", rec.t_unix_s);
    f.row.setAttribute("data-rays", rec.rays);
    if (rec.lat_deg != null) {
      f.row.setAttribute("data-lat", rec.lat_deg);
      f.row.setAttribute("data-lon", rec.lon_deg);
    }
    showText(f, rec, history, now);
    if (history) { drawFused(f, rec, history); }
    else { f.held = rec; scheduleMap(); }
  }

  function fusedCells(f, rec) {
    var sd = rec.pos_std_ned_m, ne = origin && rec.lat_deg != null ? geoNE(rec.lat_deg, rec.lon_deg) : null;
    f.row.querySelector(".rg").textContent = rec.range_m == null ? "-" : rec.range_m.toFixed(2) + " m";
    f.row.querySelector(".ne").textContent = ne ? ne[0].toFixed(2) + ", " + ne[1].toFixed(2) :
      (rec.lat_deg == null ? "-" : "no origin");
    f.row.querySelector(".sd").textContent = sd ? sd[0].toFixed(2) + ", " + sd[1].toFixed(2) : "-";
    f.row.querySelector(".age").textContent = rec.rays + " rays";
  }

  function showTarget(key, rec, history) {
    var t = target(key);
    var tp = rec.target_pos_ned_m;
    var now = Date.now();
    t.rec = rec;
    t.row.setAttribute("data-status", rec.status);
    t.row.setAttribute("data-t", rec.t_boot_s);
    if (tp) {
      t.row.setAttribute("data-n", tp[0]);
      t.row.setAttribute("data-e", tp[1]);
    }
    showText(t, rec, history, now);
    if (!tp) { return; }
    if (!history) {  // live: drawn with the map's next frame
      t.held = rec;
      scheduleMap();
    } else {
      t.hist.setLatLngs(history.map(function (p) { return vLL(t.sysid, p[0], p[1]); }));
      drawTarget(t, tp, rec.rel_pos_std_ned_m);
    }
    if (!fitted) {
      fitted = true;
      var vp = rec.vehicle_pos_ned_m || tp;
      map.fitBounds(L.latLngBounds([vLL(t.sysid, tp[0], tp[1]), vLL(t.sysid, vp[0], vp[1])]).pad(1.0));
    }
  }

  function metrePixels() {
    var a = map.latLngToLayerPoint(toLL(0, 0)), b = map.latLngToLayerPoint(toLL(1, 0));
    return Math.abs(b.y - a.y) || 1.0;
  }

  function apply() {
    scheduled = false;
    var now = Date.now();
    lastApply = now;
    var latest = heldVehicles;  // each vehicle drawn where its latest estimate puts it
    for (var key in pending) {
      var ev = pending[key];
      var rec = ev.record;
      latencies.push(now - waiting[key]);  // published to shown, the oldest event of the batch
      if (key.lastIndexOf("fused/", 0) === 0) { showFused(key.slice(6), rec, null); continue; }
      var last = latest[rec.sysid];
      if (!last || rec.t_boot_s >= last.record.t_boot_s) { latest[rec.sysid] = ev; }
      showTarget(key, rec, null);
    }
    pending = {};
    waiting = {};
    if (latencies.length > 500) { latencies = latencies.slice(-500); }
    var s = latencies.slice().sort(function (a, b) { return a - b; });
    latencyMedian = s.length ? s[Math.floor(s.length / 2)] : null;
    document.getElementById("latency").setAttribute(
      "data-median", latencyMedian === null ? "" : latencyMedian.toFixed(1));
    document.getElementById("count").setAttribute("data-events", events);
    if (!(now - countAt < TEXT_MS)) { writeCounts(now); }
    else {
      countStale = true;
      if (!textTimer) { textTimer = setTimeout(flushText, TEXT_MS); }
    }
  }

  function writeCounts(now) {
    countAt = now;
    countStale = false;
    document.getElementById("latency").textContent = "latency to this page: " +
      (latencyMedian === null ? "-" : latencyMedian.toFixed(0) + " ms (median)");
    document.getElementById("count").textContent = events + " events";
  }

  // a message is a batch: the latest estimate of each target that had one
  function onEvent(msg) {
    var batch = JSON.parse(msg.data);
    for (var i = 0; i < batch.length; i++) {
      var ev = batch[i];
      events += 1;
      if (ev.key.lastIndexOf("fused/", 0) !== 0) { noteOrigin(ev.record.sysid, ev.origin, ev.record); }
      if (!pending[ev.key]) { waiting[ev.key] = ev.sent_ms; }  // the oldest not yet shown
      pending[ev.key] = ev;
    }
    if (!scheduled) {  // now, unless the last redraw was less than REDRAW_MS ago
      scheduled = true;
      setTimeout(apply, Math.max(0, lastApply + REDRAW_MS - Date.now()));
    }
  }

  function live() {
    fetch("/state").then(function (r) { return r.json(); }).then(function (st) {
      for (var s in st.vehicles) { noteOrigin(s, st.vehicles[s].origin, null); }
      for (var k in st.targets) { var r = st.targets[k].record; noteOrigin(String(r.sysid), null, r); }
      init();
      for (var sysid in st.vehicles) {
        var v = st.vehicles[sysid];
        showVehicle(sysid, v.pos_ned_m, v.yaw_deg, v.track);
      }
      for (var key in st.targets) { showTarget(key, st.targets[key].record, st.targets[key].history); }
      for (var name in st.fused || {}) { showFused(name, st.fused[name].record, st.fused[name].history); }
      var es = new EventSource("/events");
      es.onopen = function () { document.getElementById("conn").textContent = "live"; };
      es.onerror = function () { document.getElementById("conn").textContent = "reconnecting"; };
      es.onmessage = onEvent;
    });
  }

  function lastAtOrBefore(series, t) {
    var lo = 0, hi = series.length - 1, best = -1;
    while (lo <= hi) {
      var mid = (lo + hi) >> 1;
      if (series[mid][0] <= t) { best = mid; lo = mid + 1; } else { hi = mid - 1; }
    }
    return best;
  }

  function report() {
    for (var s in REPORT.vehicles) { noteOrigin(s, REPORT.vehicles[s].origin, null); }
    init();
    var slider = document.getElementById("slider");
    var label = document.getElementById("t");
    slider.min = REPORT.t0; slider.max = REPORT.t1; slider.step = (REPORT.t1 - REPORT.t0) / 1000 || 1;
    slider.value = REPORT.t1;
    for (var sysid in REPORT.vehicles) {
      var tr = REPORT.vehicles[sysid].track;
      L.polyline(tr.map(function (p) { return vLL(sysid, p[1], p[2]); }),
                 {color: colour(sysid), weight: 1, opacity: 0.3}).addTo(map);
    }
    function at(t) {
      label.textContent = (REPORT.clock || "t_boot") + " " + t.toFixed(1) + " s";
      for (var sysid in REPORT.vehicles) {
        var trk = REPORT.vehicles[sysid].track, i = lastAtOrBefore(trk, t);
        if (i >= 0) { showVehicle(sysid, [trk[i][1], trk[i][2]], trk[i][3], trk.slice(Math.max(0, i - 300), i + 1).map(function (p) { return [p[1], p[2]]; })); }
      }
      for (var key in REPORT.targets) {
        var ser = REPORT.targets[key].series, j = lastAtOrBefore(ser, t);
        if (j < 0) { continue; }
        var p = ser[j];
        var rec = {t_boot_s: p[0], target_pos_ned_m: [p[1], p[2]], rel_pos_std_ned_m: [p[3], p[4]],
                   status: p[5], range_m: p[6], sysid: key.split("/")[0], vehicle_pos_ned_m: null};
        showTarget(key, rec, ser.slice(0, j + 1).map(function (q) { return [q[1], q[2]]; }));
      }
    }
    var pts = [];
    for (var sv in REPORT.vehicles) {
      REPORT.vehicles[sv].track.forEach(function (p) { pts.push(vLL(sv, p[1], p[2])); });
    }
    for (var k in REPORT.targets) {
      var ser = REPORT.targets[k].series;
      if (ser.length) { pts.push(vLL(k.split("/")[0], ser[ser.length - 1][1], ser[ser.length - 1][2])); }
    }
    if (pts.length) { map.fitBounds(L.latLngBounds(pts).pad(0.1)); fitted = true; }
    slider.addEventListener("input", function () { at(parseFloat(slider.value)); });
    at(REPORT.t1);
    document.body.setAttribute("data-ready", "1");
  }

  if (REPORT) { report(); } else { live(); }
})();
