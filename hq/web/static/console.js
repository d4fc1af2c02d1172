// rescue-hq console: the page's whole state arrives as JSON (GET /api/state, then
// server-sent events on /api/events); the page draws it and posts the operator's
// actions. Map: Leaflet's L.CRS.Simple, one unit = one metre; lat = north,
// lng = east of the robots' start (the EKF origin), so north is up.
"use strict";

const URGENCY_COLOUR = { CRITICAL: "#d7191c", MEDIUM: "#e66100", LIGHT: "#1a9641" };
const RESOLVED_COLOUR = "#7a7a7a";
const ROBOT_COLOURS = ["#1f5fbf", "#7b3fb5", "#0b7f86", "#b0306e", "#4a5568"];
const ACTION_LABEL = {
  confirmed: "confirmed", rescued: "rescued", false_alarm: "false alarm", look_closer: "look closer",
  looks_off: "no more looks", looks_on: "looks on",
};
const STATE_LABEL = {
  TENTATIVE: "tentative", CONFIRMED: "confirmed", NOT_SEEN_RECENTLY: "not seen recently",
  RESCUED: "rescued", FALSE_ALARM: "false alarm", MERGED: "merged",
};
const ARM_S = 4; // a decisive button must be pressed twice within this time

let state = null;
let clockOffsetS = 0; // HQ clock minus this browser's clock
let map = null;
let fitted = false;
const victimLayers = new Map(); // id -> {marker, ellipse}
const robotLayers = new Map(); // sysid -> {marker, path}
const cards = new Map(); // id -> card element
let selectedId = null;

// -- small helpers -----------------------------------------------------------------

function el(tag, props, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(props || {})) {
    if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
}

function hqNow() {
  return Date.now() / 1000 + clockOffsetS;
}

function clock(unixS) {
  return new Date(unixS * 1000).toLocaleTimeString([], { hour12: false });
}

function age(unixS) {
  const s = Math.max(0, Math.round(hqNow() - unixS));
  if (s < 60) return `${s} s ago`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${s % 60} s ago`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min ago`;
}

function signed(x) {
  return (x < 0 ? "−" : "+") + Math.abs(x).toFixed(1);
}

function robotColour(sysid) {
  return ROBOT_COLOURS[(sysid - 1) % ROBOT_COLOURS.length];
}

function victimColour(v) {
  return v.resolved ? RESOLVED_COLOUR : URGENCY_COLOUR[v.urgency] || RESOLVED_COLOUR;
}

function label(v) {
  return v.state === "RESCUED" ? `${v.label} ✓` : v.state === "FALSE_ALARM" ? `${v.label} ✗` : v.label;
}

// -- the map -------------------------------------------------------------------------

function ellipsePoints(v) {
  const { major_m: a, minor_m: b, bearing_deg: deg } = v.ellipse;
  const th = (deg * Math.PI) / 180;
  const pts = [];
  for (let i = 0; i < 48; i++) {
    const t = (2 * Math.PI * i) / 48;
    const u = a * Math.cos(t);
    const w = b * Math.sin(t);
    pts.push([v.north_m + u * Math.cos(th) - w * Math.sin(th), v.east_m + u * Math.sin(th) + w * Math.cos(th)]);
  }
  return pts;
}

function niceStep(span) {
  for (const s of [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000]) if (span / s <= 10) return s;
  return 2000;
}

const gridLayer = typeof L !== "undefined" ? L.layerGroup() : null;

function drawGrid() {
  gridLayer.clearLayers();
  const b = map.getBounds();
  const step = niceStep(Math.max(b.getNorth() - b.getSouth(), b.getEast() - b.getWest()));
  const n0 = Math.floor(b.getSouth() / step) * step;
  const e0 = Math.floor(b.getWest() / step) * step;
  for (let n = n0; n <= b.getNorth(); n += step) {
    const axis = Math.abs(n) < 1e-9;
    gridLayer.addLayer(L.polyline([[n, b.getWest()], [n, b.getEast()]], {
      color: axis ? "#5b6b7d" : "#c5cdd6", weight: axis ? 1.5 : 1, interactive: false,
    }));
    gridLayer.addLayer(L.marker([n, b.getWest()], {
      interactive: false,
      icon: L.divIcon({ className: "grid-label grid-n", html: `${n} m N`, iconSize: null }),
    }));
  }
  for (let e = e0; e <= b.getEast(); e += step) {
    const axis = Math.abs(e) < 1e-9;
    gridLayer.addLayer(L.polyline([[b.getSouth(), e], [b.getNorth(), e]], {
      color: axis ? "#5b6b7d" : "#c5cdd6", weight: axis ? 1.5 : 1, interactive: false,
    }));
    gridLayer.addLayer(L.marker([b.getNorth(), e], {
      interactive: false,
      icon: L.divIcon({ className: "grid-label grid-e", html: `${e} m E`, iconSize: null }),
    }));
  }
}

function initMap() {
  const box = document.getElementById("map");
  if (typeof L === "undefined") {
    const why = box.dataset.assetsMissing || "the map library did not load";
    box.append(el("div", { class: "map-missing" }, `No map: ${why}. The list on the right still works.`));
    return;
  }
  map = L.map(box, {
    crs: L.CRS.Simple, minZoom: -4, maxZoom: 6, zoomSnap: 0.25, attributionControl: false,
    zoomControl: false, // top right, off the grid's north labels on the left edge
  });
  L.control.zoom({ position: "topright" }).addTo(map);
  map.setView([0, 0], 3);
  gridLayer.addTo(map);
  L.control.scale({ metric: true, imperial: false, maxWidth: 160 }).addTo(map);
  L.marker([0, 0], {
    interactive: false,
    icon: L.divIcon({ className: "start-mark", html: "✚ start", iconSize: null }),
  }).addTo(map);
  const Fit = L.Control.extend({
    onAdd() {
      return el("button", { class: "fit-button", title: "Show every robot and victim", onclick: fitAll }, "Fit all");
    },
  });
  new Fit({ position: "topright" }).addTo(map);
  map.on("moveend zoomend", drawGrid);
  drawGrid();
  // The searched-area map lies under the victims, the robots and their paths.
  map.createPane("coverage").style.zIndex = 350;
  const Legend = L.Control.extend({
    onAdd() { return el("div", { id: "coverage-legend", class: "coverage-legend" }); },
  });
  new Legend({ position: "bottomleft" }).addTo(map);
}

// -- where the robots have looked (hq/coverage.py: the merged map) ----------------------

// Three shades: searched well (p >= 0.9), glanced at (p >= 0.3), not searched (looked
// at less, or never, inside the box of what the robots looked at).
const COVERAGE_RGBA = {
  "2": [26, 150, 65, 120],
  "1": [166, 217, 106, 110],
  "0": [215, 48, 39, 45],
  ".": [215, 48, 39, 45],
};
let coverageLayer = null;
let coveragePlaces = null;
let coverageFetchedMs = 0;
let coverageInFlight = false;

function pct(x) { return `${Math.round(100 * x)} %`; }

function drawCoverage(c) {
  const legend = document.getElementById("coverage-legend");
  if (coverageLayer) { coverageLayer.remove(); coverageLayer = null; }
  if (coveragePlaces) { coveragePlaces.remove(); coveragePlaces = null; }
  const s = c.summary;
  const swatch = (k) => el("span", { class: "swatch", style: `background: rgba(${COVERAGE_RGBA[k].slice(0, 3).join(",")}, ${Math.min(1, COVERAGE_RGBA[k][3] / 160)})` });
  if (legend) {
    const lines = [el("b", {}, "Searched area")];
    if (!c.box) {
      lines.push(el("div", {}, "no robot has sent where it looked yet"));
    } else {
      lines.push(
        el("div", { id: "coverage-share" }, `${pct(s.searched_well_share)} searched well · ${pct(s.glanced_at_share)} glanced at or better, of ${s.area_m2.toFixed(0)} m²`),
        el("div", {}, swatch("2"), " searched well ", swatch("1"), " glanced at ", swatch("0"), " not searched"),
      );
      c.places.forEach((p, i) => {
        const near = p.robot_sysid == null ? "" : ` · ${p.distance_m} m from R${p.robot_sysid}`;
        lines.push(el("div", { class: "place" }, `#${i + 1} unsearched ${p.area_m2.toFixed(1)} m² at N ${signed(p.north_m)} E ${signed(p.east_m)}${near}`));
      });
      if (c.unplaced.length) lines.push(el("div", { class: "warn" }, `robot ${c.unplaced.join(", ")}: no EKF origin (or one over 2 km from the others'), its map is not shown`));
      lines.push(el("div", { class: "note" }, "claimed from the cameras, no depth: floor behind tall debris counts as seen"));
    }
    legend.replaceChildren(...lines);
  }
  if (!c.box || !map) return;
  const [n0, n1, e0, e1] = c.box;
  const rows = n1 - n0 + 1;
  const cols = e1 - e0 + 1;
  const canvas = document.createElement("canvas");
  canvas.width = cols;
  canvas.height = rows;
  const ctx = canvas.getContext("2d");
  const img = ctx.createImageData(cols, rows);
  for (let r = 0; r < rows; r++) {
    const y = rows - 1 - r; // row 0 is the southmost; the image's top is north
    for (let k = 0; k < cols; k++) {
      const rgba = COVERAGE_RGBA[c.cells[r * cols + k]];
      img.data.set(rgba, 4 * (y * cols + k));
    }
  }
  ctx.putImageData(img, 0, 0);
  const m = c.cell_m;
  coverageLayer = L.imageOverlay(canvas.toDataURL(), [[n0 * m, e0 * m], [(n1 + 1) * m, (e1 + 1) * m]], {
    pane: "coverage", interactive: false, className: "coverage-layer",
  }).addTo(map);
  coveragePlaces = L.layerGroup(c.places.map((p, i) => L.marker([p.north_m, p.east_m], {
    interactive: false, pane: "coverage",
    icon: L.divIcon({ className: "place-mark", html: `#${i + 1} unsearched ${p.area_m2.toFixed(0)} m²`, iconSize: null }),
  }))).addTo(map);
}

function fetchCoverage() {
  if (coverageInFlight) return;
  coverageInFlight = true;
  coverageFetchedMs = Date.now();
  fetch("/api/coverage").then((r) => (r.ok ? r.json() : null)).then((c) => {
    if (c) { window.hqCoverage = c; drawCoverage(c); }
  }, () => {}).finally(() => { coverageInFlight = false; });
}

function fitAll() {
  if (!map || !state) return;
  const pts = [[0, 0]];
  for (const v of state.victims) pts.push([v.north_m, v.east_m]);
  for (const r of state.robots) {
    if (r.position) pts.push([r.position.north_m, r.position.east_m]);
    for (const p of r.path) pts.push(p);
  }
  map.fitBounds(L.latLngBounds(pts).pad(0.15), { maxZoom: 4 });
}

const SEEN_TITLE = "What saw this person, on any robot: colour body (the colour camera's person models), " +
  "colour part (only a hand or a face showed), warm (the thermal camera; warm only: nothing may show, look under the debris).";

function popupHtml(v) {
  const where = v.lat_deg == null ? "lat/lon unknown (no EKF origin)" : `${v.lat_deg.toFixed(6)}, ${v.lon_deg.toFixed(6)}`;
  const box = el("div", { class: "popup" },
    el("b", {}, `${v.label} ${v.urgency} · ${STATE_LABEL[v.state] || v.state}`), el("br"),
    `N ${signed(v.north_m)} m, E ${signed(v.east_m)} m, ±${v.sigma_m.toFixed(1)} m`, el("br"),
    where, el("br"),
    `robot ${v.robots.join(", ")} · ${v.visibility_pct.toFixed(0)} % visible`, el("br"),
    `seen: ${v.seen}`);
  return box;
}

function drawMap() {
  if (!map) return;
  const seen = new Set();
  for (const v of state.victims) {
    seen.add(v.id);
    const colour = victimColour(v);
    let layer = victimLayers.get(v.id);
    if (!layer) {
      const ellipse = L.polygon(ellipsePoints(v), { weight: 1, dashArray: "4 3", fillOpacity: 0.12, interactive: false });
      const marker = L.circleMarker([v.north_m, v.east_m], { radius: 8, weight: 2, color: "#fff", fillOpacity: 1 });
      marker.bindTooltip("", { permanent: true, direction: "right", offset: [8, 0], className: "victim-label" });
      marker.bindPopup("");
      marker.on("click", () => select(v.id, false));
      ellipse.addTo(map);
      marker.addTo(map);
      layer = { marker, ellipse };
      victimLayers.set(v.id, layer);
    }
    const key = JSON.stringify(v) + (v.id === selectedId);
    if (layer.key === key) continue; // unchanged: a page with hundreds of victims stays quick
    layer.key = key;
    layer.ellipse.setLatLngs(ellipsePoints(v));
    layer.ellipse.setStyle({ color: colour, fillColor: colour });
    layer.marker.setLatLng([v.north_m, v.east_m]);
    layer.marker.setStyle({ fillColor: colour, radius: v.resolved ? 6 : v.urgency === "CRITICAL" ? 10 : 8,
      color: v.id === selectedId ? "#111" : "#fff" });
    layer.marker.setTooltipContent(label(v));
    layer.marker.setPopupContent(popupHtml(v));
    layer.marker.getElement()?.setAttribute("data-victim", String(v.id));
    layer.marker.getElement()?.setAttribute("data-urgency", v.urgency);
  }
  for (const [id, layer] of victimLayers) {
    if (!seen.has(id)) {
      layer.marker.remove();
      layer.ellipse.remove();
      victimLayers.delete(id);
    }
  }
  for (const r of state.robots) {
    let layer = robotLayers.get(r.sysid);
    if (!r.position) continue;
    const colour = r.link_lost ? RESOLVED_COLOUR : robotColour(r.sysid);
    if (!layer) {
      const path = L.polyline([], { color: robotColour(r.sysid), weight: 2, opacity: 0.7, interactive: false }).addTo(map);
      const marker = L.marker([0, 0], { icon: L.divIcon({ className: "", html: "", iconSize: null }) }).addTo(map);
      layer = { path, marker };
      robotLayers.set(r.sysid, layer);
    }
    layer.path.setLatLngs(r.path.concat([[r.position.north_m, r.position.east_m]]));
    layer.marker.setLatLng([r.position.north_m, r.position.east_m]);
    const text = r.link_lost ? `R${r.sysid} link lost` : `R${r.sysid}`;
    const html = `<div class="robot-mark${r.link_lost ? " lost" : ""}" data-robot="${r.sysid}" style="background:${colour}">${text}</div>`;
    if (layer.html !== html) {
      layer.marker.setIcon(L.divIcon({ className: "robot-icon", html, iconSize: null }));
      layer.html = html;
    }
  }
  if (!fitted && (state.victims.length || state.robots.some((r) => r.position))) {
    fitted = true;
    fitAll();
  }
}

// -- the list ----------------------------------------------------------------------

async function post(url, body) {
  const resp = await fetch(url, {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  });
  const data = await resp.json().catch(() => ({ error: `HTTP ${resp.status}` }));
  if (!resp.ok) throw new Error(data.error || `HTTP ${resp.status}`);
  return data;
}

function actionButton(card, action, text, decisive) {
  const button = el("button", { class: `act act-${action}`, dataset: { action } }, text);
  let armedUntil = 0;
  button.addEventListener("click", async (ev) => {
    ev.stopPropagation();
    const now = Date.now() / 1000;
    if (decisive && now > armedUntil) {
      armedUntil = now + ARM_S;
      button.classList.add("armed");
      button.textContent = `Press again: ${text}`;
      setTimeout(() => { button.classList.remove("armed"); button.textContent = text; }, ARM_S * 1000);
      return;
    }
    armedUntil = 0;
    button.classList.remove("armed");
    button.textContent = text;
    const msg = card.querySelector(".msg");
    msg.textContent = "recording…";
    try {
      await post(`/api/victims/${card.dataset.id}/action`, { action });
      msg.textContent = "";
    } catch (e) {
      msg.textContent = `not sent: ${e.message}`;
    }
  });
  return button;
}

function makeCard(id) {
  const card = el("li", { class: "victim", id: `victim-${id}`, dataset: { id: String(id) } });
  const note = el("input", { type: "text", class: "note-input", placeholder: "note for the team…", maxlength: "500" });
  const noteForm = el("form", { class: "note-form", hidden: "" }, note, el("button", { type: "submit" }, "Add note"));
  noteForm.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const msg = card.querySelector(".msg");
    try {
      await post(`/api/victims/${id}/note`, { text: note.value });
      note.value = "";
      noteForm.hidden = true;
      msg.textContent = "";
    } catch (e) {
      msg.textContent = `note not saved: ${e.message}`;
    }
  });
  noteForm.addEventListener("click", (ev) => ev.stopPropagation());
  card.append(
    el("div", { class: "pics" },
      el("div", { class: "picture colour" }),
      el("div", { class: "picture thermal", hidden: "" })),
    el("div", { class: "body" },
      el("div", { class: "title" }),
      el("div", { class: "facts" }),
      el("div", { class: "sent" }),
      el("ul", { class: "notes" }),
      el("div", { class: "buttons" },
        actionButton(card, "confirmed", "Confirm", false),
        actionButton(card, "rescued", "Rescued", true),
        actionButton(card, "false_alarm", "False alarm", true),
        actionButton(card, "look_closer", "Look closer", false),
        el("button", { class: "act act-note", onclick: (ev) => {
          ev.stopPropagation();
          noteForm.hidden = !noteForm.hidden;
          if (!noteForm.hidden) note.focus();
        } }, "Note…")),
      noteForm,
      el("div", { class: "msg" })),
  );
  card.addEventListener("click", () => select(id, true));
  return card;
}

function fillCard(card, v) {
  card.style.borderLeftColor = victimColour(v);
  card.classList.toggle("resolved", v.resolved);
  card.classList.toggle("selected", v.id === selectedId);
  card.dataset.state = v.state;
  card.dataset.urgency = v.urgency;
  const pic = card.querySelector(".picture.colour");
  const warm = card.querySelector(".picture.thermal");
  if (v.thermal_picture) {
    if (warm.dataset.src !== v.thermal_picture) {
      warm.replaceChildren(el("a", { href: v.thermal_picture, target: "_blank", title: "the thermal camera's view (false colour, with its temperature scale): open it full size" },
        el("img", { src: v.thermal_picture, alt: `thermal picture of victim ${v.id}` })));
      warm.dataset.src = v.thermal_picture;
    }
    warm.hidden = false;
  } else {
    warm.replaceChildren();
    warm.dataset.src = "";
    warm.hidden = true;
  }
  card.querySelector(".pics").classList.toggle("two", Boolean(v.thermal_picture));
  if (v.picture) {
    if (pic.dataset.src !== v.picture) {
      pic.replaceChildren(el("a", { href: v.picture, target: "_blank", title: "the robot's evidence picture: open it full size" },
        el("img", { src: v.picture, alt: `evidence picture of victim ${v.id}` })));
      pic.dataset.src = v.picture;
    }
  } else if (pic.dataset.src !== "none") {
    pic.replaceChildren(el("span", { title: "No robot has sent an evidence picture of this victim yet (a robot sends one once it has a clear view; over a radio it takes several seconds)." }, "no picture", el("br"), "from robot"));
    pic.dataset.src = "none";
  }
  card.querySelector(".title").replaceChildren(
    el("span", { class: "vid", title: `the HQ's victim ${v.id}: QGC's map label, and what the robots say once the HQ has answered` }, v.label),
    el("span", { class: `badge u-${v.urgency}` }, v.urgency),
    el("span", { class: `state s-${v.state}` }, STATE_LABEL[v.state] || v.state),
  );
  const where = v.lat_deg == null ? "lat/lon unknown" : `${v.lat_deg.toFixed(6)}, ${v.lon_deg.toFixed(6)}`;
  card.querySelector(".facts").replaceChildren(
    el("div", {}, `N ${signed(v.north_m)} m  E ${signed(v.east_m)} m  ±${v.sigma_m.toFixed(1)} m · ${where}`),
    el("div", {}, `robot ${v.robots.join(", ")} · ${v.visibility_pct.toFixed(0)} % visible · ${v.sightings} sightings`),
    el("div", { class: "seen", title: SEEN_TITLE }, `seen: ${v.seen}`),
    el("div", {}, `first seen ${clock(v.first_seen_unix_s)} · last seen `,
      el("span", { class: "t", dataset: { t: v.last_seen_unix_s } }, "")),
  );
  const sent = card.querySelector(".sent");
  const latest = new Map();
  for (const a of v.actions) latest.set(a.robot, a);
  sent.replaceChildren(...[...latest.values()].map(actionLine));
  card.querySelector(".notes").replaceChildren(...v.notes.map((n) =>
    el("li", {}, el("span", { class: "note-time" }, clock(n.created_unix_s)), " ", n.text)));
  tickTimes(card);
}

// One robot's answer to the newest action sent to it: applied, refused (and why:
// the victim then stays as the robots report it), or still being sent.
function actionLine(a) {
  const what = ACTION_LABEL[a.action] || a.action;
  const status = a.rejected ? "rejected" : a.acked ? "acked" : "pending";
  const text = a.rejected ? `${what}: robot ${a.robot} ${a.why}`
    : a.acked ? `${what}: robot ${a.robot} acknowledged ✓`
      : `${what}: sending to robot ${a.robot}…`;
  return el("div", { class: status, dataset: { seq: String(a.seq), acked: String(a.acked), status } },
    a.rejected ? "✗ " : "", text);
}

function tickTimes(root) {
  for (const span of root.querySelectorAll(".t")) {
    const t = Number(span.dataset.t);
    span.textContent = `${clock(t)} (${age(t)})`;
  }
}

function drawList() {
  const list = document.getElementById("victims");
  const seen = new Set();
  state.victims.forEach((v, i) => {
    seen.add(v.id);
    let card = cards.get(v.id);
    if (!card) {
      card = makeCard(v.id);
      cards.set(v.id, card);
    }
    const key = JSON.stringify(v);
    if (card.hqKey !== key) {
      card.hqKey = key;
      fillCard(card, v);
    }
    if (list.children[i] !== card) list.insertBefore(card, list.children[i] || null);
  });
  for (const [id, card] of cards) {
    if (!seen.has(id)) {
      card.remove();
      cards.delete(id);
    }
  }
  document.getElementById("empty").hidden = state.victims.length > 0;
  const robots = document.getElementById("robots");
  const lines = state.robots.map(robotLine);
  if (lines.length !== robots.children.length || lines.some((line, i) => robots.children[i] !== line)) {
    robots.replaceChildren(...lines);
  }
}

// One robot's line, made again only when what it shows changed (its button stays
// the same element between states, so a click is never lost to a redraw).
const robotLines = new Map(); // sysid -> {key, line}
function robotLine(r) {
  const key = JSON.stringify([r.link_lost, r.link_lost ? r.last_heard_unix_s : 0, r.status,
    r.looks_action, robotMsgs.get(r.sysid) || ""]);
  const held = robotLines.get(r.sysid);
  if (held && held.key === key) return held.line;
  const line = makeRobotLine(r);
  robotLines.set(r.sysid, { key, line });
  return line;
}

function makeRobotLine(r) {
  const s = r.status;
  const health = r.link_lost
    ? (r.last_heard_unix_s > 0 ? `last heard ${clock(r.last_heard_unix_s)}` : "never heard")
    : s ? `${s.fps.toFixed(1)} fps · outbox ${s.outbox_pending}` : "no status yet";
  const line = el("span", { class: `robot${r.link_lost ? " lost" : ""}`, dataset: { robot: String(r.sysid) },
    style: `border-color:${robotColour(r.sysid)}` },
  `R${r.sysid} `, el("b", {}, r.link_lost ? "LINK LOST" : "link ok"), ` · ${health}`);
  if (s) line.append(" · ", el("span", { class: `looks${s.looks_on ? " on" : ""}`, title: LOOKS_TITLE }, s.looks), " ", looksButton(r));
  const a = r.looks_action;
  if (a) line.append(" ", el("span", { class: `looks-sent ${a.rejected ? "rejected" : a.acked ? "acked" : "pending"}`, title: a.why || "" },
    a.rejected ? `${ACTION_LABEL[a.action]}: rejected` : a.acked ? `${ACTION_LABEL[a.action]} ✓` : `${ACTION_LABEL[a.action]}: sending…`));
  const msg = robotMsgs.get(r.sysid);
  if (msg) line.append(" ", el("span", { class: "msg" }, msg));
  return line;
}

const LOOKS_TITLE = "Closer looks: the robot leaves its route for a short detour to look again at a " +
  "possible victim it cannot settle, then resumes its mission (only armed and in AUTO; any mode change " +
  "by the operator ends it). Its parameter RC_LOOK_ON in QGC is the same switch.";
const robotMsgs = new Map(); // sysid -> why the last looks off/on was not recorded

// "No more looks" while the robot's looks are on, "Looks on" while off: recorded at the
// HQ and sent to the robot until it acknowledges, as every action.
function looksButton(r) {
  const on = r.status.looks_on;
  const button = el("button", { class: `act act-looks-${on ? "off" : "on"}`, dataset: { looks: on ? "off" : "on" } },
    on ? "No more looks" : "Looks on");
  button.addEventListener("click", async (ev) => {
    ev.stopPropagation();
    try {
      await post(`/api/robots/${r.sysid}/looks`, { looks: button.dataset.looks });
      robotMsgs.delete(r.sysid);
    } catch (e) {
      robotMsgs.set(r.sysid, `not sent: ${e.message}`);
      if (state) drawList();
    }
  });
  return button;
}

function select(id, fromList) {
  selectedId = id;
  for (const [cid, card] of cards) card.classList.toggle("selected", cid === id);
  const layer = victimLayers.get(id);
  if (layer && fromList) {
    map.panTo(layer.marker.getLatLng());
    layer.marker.openPopup();
  }
  if (!fromList) cards.get(id)?.scrollIntoView({ block: "nearest", behavior: "smooth" });
  if (state) drawMap();
}

// -- banners and header ------------------------------------------------------------

function drawBanners(connected) {
  const box = document.getElementById("banners");
  const items = [];
  if (!connected) {
    items.push(el("div", { class: "banner hq-lost", id: "banner-hq" },
      "Connection to rescue-hq lost: this page is not updating. Retrying…"));
  }
  for (const r of state ? state.robots : []) {
    if (!r.link_lost) continue;
    const heard = r.last_heard_unix_s > 0 ? `last heard ${clock(r.last_heard_unix_s)} (${age(r.last_heard_unix_s)})` : "never heard";
    items.push(el("div", { class: "banner link-lost", dataset: { robot: String(r.sysid) } },
      el("b", {}, `LINK LOST: robot ${r.sysid}`),
      ` · ${heard}. Its victims are as last reported; actions for it wait until it is heard again.`));
  }
  box.replaceChildren(...items);
}

function drawHeader() {
  const open = state.victims.filter((v) => !v.resolved);
  const critical = open.filter((v) => v.urgency === "CRITICAL").length;
  document.getElementById("counts").textContent =
    `${open.length} open victim${open.length === 1 ? "" : "s"} (${critical} critical) · ` +
    `${state.victims.length - open.length} resolved · ${state.robots.length} robot${state.robots.length === 1 ? "" : "s"}`;
}

let connected = false;

function render(newState) {
  state = newState;
  clockOffsetS = state.now_unix_s - Date.now() / 1000;
  drawHeader();
  drawBanners(connected);
  drawList();
  drawMap();
  if (Date.now() - coverageFetchedMs > 3000) fetchCoverage(); // at most every 3 s
  document.body.dataset.rendered = String(Date.now());
  if (window.hqFirstRenderMs === undefined) window.hqFirstRenderMs = performance.now();
  window.dispatchEvent(new CustomEvent("hq-state", { detail: state }));
}

function setConnected(ok) {
  connected = ok;
  const conn = document.getElementById("conn");
  conn.textContent = ok ? "live" : "reconnecting…";
  conn.className = `conn ${ok ? "ok" : "bad"}`;
  drawBanners(ok);
}

function connect() {
  const source = new EventSource("/api/events");
  source.addEventListener("open", () => setConnected(true));
  source.addEventListener("error", () => {
    setConnected(false);
    // A restarted rescue-hq with a (new) token answers 401: back to its sign-in page.
    fetch("/api/state").then((r) => { if (r.status === 401) location.reload(); }, () => {});
    // Refused (503: the console serves as many pages as it can): the browser gives
    // up on such a stream, so try again a little later.
    if (source.readyState === EventSource.CLOSED) setTimeout(connect, 5000);
  });
  source.addEventListener("state", (ev) => {
    if (!connected) setConnected(true);
    render(JSON.parse(ev.data));
  });
}

initMap();
connect();
setInterval(() => { if (Date.now() - coverageFetchedMs > 10000) fetchCoverage(); }, 5000);
setInterval(() => {
  document.getElementById("clock").textContent = `HQ ${clock(hqNow())}`;
  tickTimes(document);
  if (state) drawBanners(connected);
}, 1000);
