// The index: the live axes, refreshed every second (axes appear and vanish with their
// liveliness tokens).
"use strict";

async function refresh() {
  let axes = [];
  try {
    const response = await fetch("/api/axes");
    if (response.ok) axes = await response.json();
  } catch (e) {
    return;
  }
  const body = document.querySelector("#axes tbody");
  body.replaceChildren(...axes.map(row));
  document.getElementById("none").hidden = axes.length > 0;
}

function row(axis) {
  const tr = document.createElement("tr");
  tr.id = "axis-" + axis.name;
  const link = document.createElement("a");
  link.href = "/axis/" + encodeURIComponent(axis.name);
  link.textContent = axis.name;
  const state = axis.moving === null ? "?" : axis.moving ? "moving" : "idle";
  const cells = [link, axis.desc ?? "", axis.rbv ?? "?", axis.egu ?? "", state];
  for (const content of cells) {
    const td = document.createElement("td");
    td.append(content);
    tr.append(td);
  }
  tr.lastChild.className = state;
  return tr;
}

refresh();
setInterval(refresh, 1000);
