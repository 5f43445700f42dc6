// One axis's screen: cells built from the field catalogue (/api/fields), live over a WebSocket
// bridged to the axis's keys; writes are confirmed by the node, a refusal shows its words.
"use strict";

let axis = location.pathname.split("/").pop();
try {
  axis = decodeURIComponent(axis);
} catch {
  // A malformed escape (`/axis/m%`): the server says the name is no axis's.
}
document.getElementById("axis").textContent = axis;
document.title = "zmotor " + axis;

const catalogue = {};
let mstaBits = [];
const values = {};
const cells = {}; // field -> [elements showing it]
let nextId = 1;
const WINDOW_MS = 60000;
// The plot's series: [time ms, value].
const series = { RBV: [], VAL: [], velocity: [] };
// For tests and curious users: what the plot holds.
window.zmotorPlot = series;

// The socket, opened again after it closes (the server or the node restarted, the network cut):
// the new one's first messages are the axis's values; nothing the page sent before is sent again.
let socket;
let reconnectDelay = 500;
function connect() {
  socket = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws/" + encodeURIComponent(axis));
  socket.onopen = () => { reconnectDelay = 500; };
  socket.onmessage = (event) => receive(JSON.parse(event.data));
  socket.onclose = () => {
    badge("live", "disconnected, reconnecting", "gone");
    setTimeout(connect, reconnectDelay);
    reconnectDelay = Math.min(reconnectDelay * 2, 5000);
  };
}
connect();
// For tests: the socket now.
window.zmotorSocket = () => socket;

fetch("/api/fields").then((r) => r.json()).then((c) => {
  for (const f of c.fields) catalogue[f.name] = f;
  mstaBits = c.msta_bits;
  build();
  for (const [field, value] of Object.entries(values)) show(field, value);
});

function receive(message) {
  if ("field" in message) {
    values[message.field] = message.value;
    if (message.field === "ERR") return showError(message.value);
    track(message.field, message.value);
    show(message.field, message.value);
  } else if ("live" in message) {
    badge("live", message.live ? "live" : "gone", message.live ? "" : "gone");
    document.getElementById("unserved").hidden = true;
  } else if (message.served === false) {
    // Nobody serves this axis: say so rather than "connecting" over empty cells.
    badge("live", "not served", "gone");
    document.getElementById("unserved").hidden = false;
  } else if (message.error) {
    showError(message.error);
  } else if (message.ok) {
    showError("");
  }
}

function write(field, value) {
  // A closed socket drops what it is given without a word: the page says it.
  if (socket.readyState !== WebSocket.OPEN) return showError(field + ": not sent, the page is not connected (it reconnects by itself)");
  socket.send(JSON.stringify({ id: nextId++, field, value: String(value) }));
}

function showError(text) {
  document.getElementById("error").textContent = text;
}

function badge(id, text, state) {
  const element = document.getElementById(id);
  element.textContent = text;
  element.className = "badge " + (state || "");
  element.hidden = text.trim() === "";
}

// A cell per field: writable fields are inputs (menus: selects), the others text.
function cell(name) {
  const def = catalogue[name];
  if (!def) return document.createTextNode("");
  let element;
  if (def.access === "R") {
    element = document.createElement("span");
  } else if (def.choices) {
    element = document.createElement("select");
    def.choices.forEach((choice, index) => element.append(new Option(choice, index)));
    element.addEventListener("change", () => write(name, element.value));
  } else {
    element = document.createElement("input");
    element.addEventListener("keydown", (event) => {
      if (event.key === "Enter") write(name, element.value);
    });
    element.addEventListener("blur", () => show(name, values[name]));
  }
  element.dataset.field = name;
  element.title = def.name + ": " + def.prompt;
  (cells[name] ||= []).push(element);
  return element;
}

function build() {
  for (const td of document.querySelectorAll("[data-cell]")) td.append(cell(td.dataset.cell));
  for (const span of document.querySelectorAll("header [data-field]")) (cells[span.dataset.field] ||= []).push(span);
  for (const table of document.querySelectorAll("table.fields")) {
    for (const name of table.dataset.fields.split(" ").filter((n) => catalogue[n])) {
      const tr = table.insertRow();
      const th = document.createElement("th");
      th.textContent = name;
      th.title = catalogue[name].prompt;
      tr.append(th);
      tr.insertCell().append(cell(name));
    }
  }
  for (const button of document.querySelectorAll("[data-write]")) {
    button.addEventListener("click", () => write(button.dataset.write, button.dataset.value));
  }
  // A jog lasts while the button is held (and ends with this page: the socket holds it).
  for (const button of document.querySelectorAll("[data-hold]")) {
    const field = button.dataset.hold;
    let held = false;
    const press = (event) => {
      if (event.button !== 0) return; // the main button only: a context menu must not jog
      event.preventDefault();
      held = true;
      write(field, 1);
    };
    const release = () => { if (held) { held = false; write(field, 0); } };
    button.addEventListener("pointerdown", press);
    // Whatever ends the press ends the jog: the button let go or left, the pointer taken away
    // (a touch cancelled), the window left or the page hidden.
    for (const ending of ["pointerup", "pointerleave", "pointercancel"]) {
      button.addEventListener(ending, release);
    }
    window.addEventListener("blur", release);
    document.addEventListener("visibilitychange", () => { if (document.hidden) release(); });
  }
}

// A value as text: menus by choice, EGU-valued numbers at PREC.
function text(name, value) {
  const def = catalogue[name];
  if (value === undefined || value === null) return "";
  if (def && def.choices && typeof value === "number") return def.choices[value] ?? String(value);
  if (def && typeof value === "number" && def.unit.includes("EGU") && def.type !== "LONG") {
    const precision = Math.max(0, Math.min(15, Number(values.PREC ?? 3)));
    return value.toFixed(precision);
  }
  return String(value);
}

function show(name, value) {
  if (name === "PREC") {
    // Every number at PREC: those shown before it came are shown again.
    for (const [other, shown] of Object.entries(values)) if (other !== "PREC") showCells(other, shown);
  }
  showCells(name, value);
}

function showCells(name, value) {
  for (const element of cells[name] || []) {
    if (element.tagName === "SELECT") element.value = String(value);
    else if (element.tagName === "INPUT") {
      if (document.activeElement !== element) element.value = text(name, value);
    } else element.textContent = text(name, value);
  }
  if (name === "DMOV") badge("motion", value === 0 ? "moving" : "done", value === 0 ? "moving" : "");
  if (name === "SEVR" || name === "STAT") {
    const sevr = catalogue.SEVR ? text("SEVR", values.SEVR) : "";
    badge("alarm", sevr === "NO_ALARM" ? "" : sevr + " " + text("STAT", values.STAT), sevr);
  }
  if (name === "MSTA") showBits(value);
}

function showBits(msta) {
  const list = document.getElementById("msta");
  list.replaceChildren(...mstaBits.map((bit) => {
    const li = document.createElement("li");
    li.textContent = bit.name;
    li.title = bit.meaning;
    li.className = msta & bit.mask ? "on" : "";
    return li;
  }));
}

// The plot: RBV and VAL over the last minute, and the velocity RBV's changes give.
function track(name, value) {
  const now = Date.now();
  if (name === "DMOV" && value === 1) series.velocity.push([now, 0]);
  if ((name !== "RBV" && name !== "VAL") || typeof value !== "number") return;
  const points = series[name];
  if (name === "RBV" && points.length) {
    const [t, last] = points[points.length - 1];
    if (now > t) series.velocity.push([now, ((value - last) * 1000) / (now - t)]);
  }
  points.push([now, value]);
}

function draw(canvas, lines, now) {
  const context = canvas.getContext("2d");
  const { width, height } = canvas;
  context.clearRect(0, 0, width, height);
  const visible = lines.map(([points]) => points.filter(([t]) => t >= now - WINDOW_MS));
  const all = visible.flat().map(([, v]) => v);
  if (all.length === 0) return;
  let low = Math.min(...all), high = Math.max(...all);
  if (high - low < 1e-9) { high += 0.5; low -= 0.5; }
  const x = (t) => ((t - (now - WINDOW_MS)) / WINDOW_MS) * (width - 50) + 45;
  const y = (v) => height - 10 - ((v - low) / (high - low)) * (height - 20);
  context.fillStyle = "#66708a";
  context.font = "11px sans-serif";
  context.fillText(high.toPrecision(4), 2, 12);
  context.fillText(low.toPrecision(4), 2, height - 4);
  visible.forEach((points, i) => {
    context.strokeStyle = lines[i][1];
    context.lineWidth = 1.5;
    context.beginPath();
    points.forEach(([t, v], j) => {
      // Hold each value until the next (a readback is a sample, not a ramp).
      if (j === 0) context.moveTo(x(t), y(v));
      else { context.lineTo(x(t), y(points[j - 1][1])); context.lineTo(x(t), y(v)); }
    });
    if (points.length) context.lineTo(x(now), y(points[points.length - 1][1]));
    context.stroke();
  });
}

setInterval(() => {
  const now = Date.now();
  for (const points of Object.values(series)) {
    while (points.length > 1 && points[1][0] < now - WINDOW_MS) points.shift();
  }
  draw(document.getElementById("position"), [[series.RBV, "#1565c0"], [series.VAL, "#ef6c00"]], now);
  draw(document.getElementById("velocity"), [[series.velocity, "#6a1b9a"]], now);
}, 200);
