// The live map and the replay report: the estimates of mav-observer on a Leaflet map, in the
// local NED frame (a metric grid, offline) or on a tile layer when one is set and the origin
// is known. Live: /state then /events (server-sent events). Report: window.REPORT and a slider.
(function () {
  "use strict";
  var CFG = window.MAP_CONFIG || {};
  var REPORT = window.REPORT || null;
  var R_EARTH = 6378137.0;
  var origin = null;
  var mode = "local";
  var map, gridLayer;
  var vehicles = {};
  var targets = {};
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
    if (mode === "tiles") {
      var lat0 = origin.lat * Math.PI / 180;
      return [origin.lat + n / R_EARTH * 180 / Math.PI,
              origin.lon + e / (R_EARTH * Math.cos(lat0)) * 180 / Math.PI];
    }
    return [n, e];
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
      L.marker([n, b.getWest()], {icon: L.divIcon({className: "grid-label", html: "N " + n + " m"}),
                                  interactive: false}).addTo(gridLayer);
    }
    for (var e = Math.floor(b.getWest() / s) * s; e <= b.getEast(); e += s) {
      L.polyline([[b.getSouth(), e], [b.getNorth(), e]],
                 {color: e === 0 ? "#999" : "#ddd", weight: 1, interactive: false}).addTo(gridLayer);
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
    origin = {lat: o.lat_deg, lon: o.lon_deg, alt: o.alt_m};
    var el = document.getElementById("origin");
    if (el) {
      el.textContent = "origin: " + origin.lat.toFixed(7) + ", " + origin.lon.toFixed(7) +
        (o.source ? " (" + o.source + ")" : "") + "; north up, metres in the local frame";
    }
  }

  function vehicle(sysid) {
    var v = vehicles[sysid];
    if (!v) {
      v = vehicles[sysid] = {
        track: L.polyline([], {color: "#0969da", weight: 2, opacity: 0.6}).addTo(map),
        marker: L.circleMarker([0, 0], {radius: 6, color: "#0969da", fillOpacity: 0.9}).addTo(map),
        heading: L.polyline([], {color: "#0969da", weight: 3}).addTo(map)
      };
      v.marker.bindTooltip("vehicle " + sysid);
    }
    return v;
  }

  function target(key) {
    var t = targets[key];
    if (!t) {
      t = targets[key] = {
        hist: L.polyline([], {color: "#8250df", weight: 1, opacity: 0.7}).addTo(map),
        e2: L.polygon([], {color: "#cf222e", weight: 1, fillOpacity: 0.08}).addTo(map),
        e1: L.polygon([], {color: "#cf222e", weight: 2, fillOpacity: 0.15}).addTo(map),
        marker: L.circleMarker([0, 0], {radius: 5, color: "#cf222e", fillOpacity: 1}).addTo(map),
        row: null
      };
      t.marker.bindTooltip(key);
      var tr = document.createElement("tr");
      tr.setAttribute("data-key", key);
      tr.innerHTML = "<td>" + key + "</td><td class='st'></td><td class='rg'></td>" +
        "<td class='ne'></td><td class='sd'></td><td class='age muted'></td>";
      document.querySelector("#targets tbody").appendChild(tr);
      t.row = tr;
    }
    return t;
  }

  function showVehicle(sysid, pos, yawDeg, track, t) {
    var v = vehicle(sysid);
    if (!pos) { return; }
    v.marker.setLatLng(toLL(pos[0], pos[1]));
    if (track) { v.track.setLatLngs(track.map(function (p) { return toLL(p[0], p[1]); })); }
    else { extend(v, v.track, toLL(pos[0], pos[1]), t); }
    if (yawDeg !== null && yawDeg !== undefined) {
      var y = yawDeg * Math.PI / 180, len = 5;
      v.heading.setLatLngs([toLL(pos[0], pos[1]),
                            toLL(pos[0] + len * Math.cos(y), pos[1] + len * Math.sin(y))]);
    }
  }

  function writeText(t, rec, now) {
    var tp = rec.target_pos_ned_m, sd = rec.rel_pos_std_ned_m;
    t.textAt = now;
    t.status = rec.status;
    t.stale = null;
    t.row.querySelector(".st").textContent = rec.status;
    t.row.querySelector(".st").className = "st " + rec.status;
    t.row.querySelector(".rg").textContent = rec.range_m.toFixed(2) + " m";
    t.row.querySelector(".age").textContent = "t " + rec.t_boot_s.toFixed(1) + " s";
    if (tp) { t.row.querySelector(".ne").textContent = tp[0].toFixed(2) + ", " + tp[1].toFixed(2); }
    if (tp && sd) { t.row.querySelector(".sd").textContent = sd[0].toFixed(2) + ", " + sd[1].toFixed(2); }
  }

  // a row's text (or the page's counts) held back is written once TEXT_MS has passed, should no newer estimate come
  function flushText() {
    textTimer = null;
    var now = Date.now();
    for (var k in targets) { if (targets[k].stale) { writeText(targets[k], targets[k].stale, now); } }
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
      extend(t, t.hist, toLL(tp[0], tp[1]), rec.t_boot_s);
      var sn = sd ? sd[0] : 0, se = sd ? sd[1] : 0, d = t.drawn;
      if (d && ppm * Math.max(Math.abs(tp[0] - d[0]), Math.abs(tp[1] - d[1]),
                              Math.abs(sn - d[2]), Math.abs(se - d[3])) < 1.0) {
        continue;  // not a pixel's change on the map
      }
      drawTarget(t, tp, sd);
    }
  }

  function drawTarget(t, tp, sd) {
    t.drawn = [tp[0], tp[1], sd ? sd[0] : 0, sd ? sd[1] : 0];
    t.marker.setLatLng(toLL(tp[0], tp[1]));
    if (sd) {
      t.e1.setLatLngs(ring(tp[0], tp[1], sd[0], sd[1], 1));
      t.e2.setLatLngs(ring(tp[0], tp[1], sd[0], sd[1], 2));
    }
  }

  function showTarget(key, rec, history) {
    var t = target(key);
    var tp = rec.target_pos_ned_m;
    var now = Date.now();
    t.row.setAttribute("data-status", rec.status);
    t.row.setAttribute("data-t", rec.t_boot_s);
    if (tp) {
      t.row.setAttribute("data-n", tp[0]);
      t.row.setAttribute("data-e", tp[1]);
    }
    if (history || rec.status !== t.status || !(now - t.textAt < TEXT_MS)) {
      writeText(t, rec, now);
    } else {
      t.stale = rec;
      if (!textTimer) { textTimer = setTimeout(flushText, TEXT_MS); }
    }
    if (!tp) { return; }
    if (!history) {  // live: drawn with the map's next frame
      t.held = rec;
      scheduleMap();
    } else {
      t.hist.setLatLngs(history.map(function (p) { return toLL(p[0], p[1]); }));
      drawTarget(t, tp, rec.rel_pos_std_ned_m);
    }
    if (!fitted) {
      fitted = true;
      var vp = rec.vehicle_pos_ned_m || tp;
      map.fitBounds(L.latLngBounds([toLL(tp[0], tp[1]), toLL(vp[0], vp[1])]).pad(1.0));
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
      var last = latest[rec.sysid];
      if (!last || rec.t_boot_s >= last.record.t_boot_s) { latest[rec.sysid] = ev; }
      showTarget(key, rec, null);
      latencies.push(now - waiting[key]);  // published to shown, the oldest event of the batch
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
      if (ev.origin) { setOrigin(ev.origin); }
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
      for (var s in st.vehicles) { if (st.vehicles[s].origin) { setOrigin(st.vehicles[s].origin); } }
      init();
      for (var sysid in st.vehicles) {
        var v = st.vehicles[sysid];
        showVehicle(sysid, v.pos_ned_m, v.yaw_deg, v.track);
      }
      for (var key in st.targets) { showTarget(key, st.targets[key].record, st.targets[key].history); }
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
    for (var s in REPORT.vehicles) { if (REPORT.vehicles[s].origin) { setOrigin(REPORT.vehicles[s].origin); } }
    init();
    var slider = document.getElementById("slider");
    var label = document.getElementById("t");
    slider.min = REPORT.t0; slider.max = REPORT.t1; slider.step = (REPORT.t1 - REPORT.t0) / 1000 || 1;
    slider.value = REPORT.t1;
    for (var sysid in REPORT.vehicles) {
      var tr = REPORT.vehicles[sysid].track;
      L.polyline(tr.map(function (p) { return toLL(p[1], p[2]); }),
                 {color: "#0969da", weight: 1, opacity: 0.3}).addTo(map);
    }
    function at(t) {
      label.textContent = "t_boot " + t.toFixed(1) + " s";
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
      REPORT.vehicles[sv].track.forEach(function (p) { pts.push(toLL(p[1], p[2])); });
    }
    for (var k in REPORT.targets) {
      var ser = REPORT.targets[k].series;
      if (ser.length) { pts.push(toLL(ser[ser.length - 1][1], ser[ser.length - 1][2])); }
    }
    if (pts.length) { map.fitBounds(L.latLngBounds(pts).pad(0.1)); fitted = true; }
    slider.addEventListener("input", function () { at(parseFloat(slider.value)); });
    at(REPORT.t1);
    document.body.setAttribute("data-ready", "1");
  }

  if (REPORT) { report(); } else { live(); }
})();
