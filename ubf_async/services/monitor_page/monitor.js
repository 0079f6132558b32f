// The tree monitor's page (ubf_async/services/monitor.py; docs/monitor.md). Plain JavaScript
// and SVG, no library: the page must work on a robot's network with nothing fetched.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const NODE_W = 160, NODE_H = 50, GAP_X = 18, GAP_Y = 46;
const $ = (id) => document.getElementById(id);

const page = {
  ws: null, allowChanges: false, historyS: 30,
  tree: null,          // the tree service's reply: {tree, slots, version}
  frames: [],          // {t, trace, drive} of the frames received, last historyS seconds
  ticks: [],           // [n, t, tick, winners] of every tick, last historyS seconds
  latest: null,        // the newest frame
  live: true,          // false while looking back with the slider
  openState: new Set(),
  nextId: 1,
};

// -- the connection ---------------------------------------------------------------------------

function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  page.ws = ws;
  setConnection("connecting", "connecting…");
  ws.onopen = () => setConnection("open", "connected");
  ws.onclose = () => {
    setConnection("closed", "disconnected: retrying");
    setTimeout(connect, 1000);  // the robot or the monitor restarted: come back by itself
  };
  ws.onmessage = (event) => {
    const msg = JSON.parse(event.data);
    if (msg.type === "hello") hello(msg);
    else if (msg.type === "tree") tree(msg);
    else if (msg.type === "frame") frame(msg);
    else if (msg.type === "reply") reply(msg);
  };
}

function setConnection(state, text) {
  const el = $("connection");
  el.dataset.state = state;
  el.textContent = text;
}

function send(request) {
  const id = page.nextId++;
  page.ws.send(JSON.stringify({ id, request }));
  showReply("pending", `${request.op}: sent…`);
  return id;
}

// -- messages ---------------------------------------------------------------------------------

function hello(msg) {
  $("robot").textContent = msg.robot;
  document.title = `${msg.robot} · ubf_async tree monitor`;
  page.allowChanges = msg.allow_changes;
  page.historyS = msg.history_s;
  $("history").textContent = String(msg.history_s);
  $("changes-note").textContent = msg.allow_changes ? "Applied between two ticks once the " +
    "robot has checked them; a refused change leaves the tree as it was." :
    `Changes are off: ${msg.refusal}`;
  for (const form of document.querySelectorAll("aside form"))
    for (const el of form.elements) el.disabled = !msg.allow_changes;
  const list = $("arbiters");
  list.replaceChildren(...(msg.arbiters || []).map((name) => {
    const option = document.createElement("option");
    option.value = name;
    return option;
  }));
}

function tree(msg) {
  page.tree = msg;
  $("tree-note").textContent = msg.version != null ? `(changes applied: ${msg.version})` : "";
  const composites = [];
  walk(msg.tree, [], (node, path) => { if (node.kind === "composite") composites.push([node, path]); });
  const select = $("composite");
  const chosen = select.value;
  select.replaceChildren(...composites.map(([node]) => option(node.name, `${node.name} <${node.arbiter}>`)));
  if (composites.some(([node]) => node.name === chosen)) select.value = chosen;
  fillChildren();
  render();
}

function frame(msg) {
  page.latest = msg;
  const t = msg.trace ? msg.trace.t : (msg.drive ? msg.drive.t : null);
  if (msg.trace) {
    page.frames.push({ t, trace: msg.trace, drive: msg.drive });
    prune(page.frames, (f) => f.t, t);
  }
  for (const tick of msg.ticks) page.ticks.push(tick);
  if (t != null) prune(page.ticks, (tick) => tick[1], t);
  const scrub = $("scrub");
  scrub.max = String(Math.max(0, page.frames.length - 1));
  if (page.live) scrub.value = scrub.max;
  render();
}

function prune(list, timeOf, now) {
  while (list.length && now - timeOf(list[0]) > page.historyS) list.shift();
  if (list.length && now < timeOf(list[0])) list.splice(0, list.length - 1);  // time went back: a new run
}

function reply(msg) {
  if (msg.ok) showReply("ok", `${msg.op}: done (changes applied: ${msg.version})`);
  else showReply("refused", `${msg.op || "request"} refused: ${msg.error}`);
}

function showReply(kind, text) {
  const el = $("reply");
  el.className = kind;
  el.textContent = text;
}

// -- drawing ----------------------------------------------------------------------------------

function shown() {
  if (page.live || !page.frames.length) return page.latest && { ...page.latest };
  const f = page.frames[Number($("scrub").value)] || page.frames[page.frames.length - 1];
  return { ...page.latest, trace: f.trace, drive: f.drive };
}

function render() {
  const view = shown();
  drawHeader(view);
  drawTree(view && view.trace);
  drawStrip(view && view.trace);
  if (view) {
    drawSources(view.status);
    drawState(view.state);
  }
}

function drawHeader(view) {
  if (!view) return;
  const trace = view.trace, drive = view.drive, status = view.status;
  $("clock").textContent = trace ? `t ${trace.t.toFixed(2)} s · tick ${trace.tick}` +
    (status && status.rate_hz ? ` · ${status.rate_hz.toFixed(1)} Hz` : "") : "";
  $("drive").textContent = drive ? `drive ${signed(drive.speed)}/${signed(drive.turn)} ` +
    `won by ${(drive.winners || []).join(", ") || "nobody"}` : "";
  const alarms = [];
  if (status && status.quarantined && status.quarantined.length) alarms.push(`QUARANTINED ${status.quarantined.join(",")}`);
  if (status && status.tick_faults) alarms.push(`TICK FAULTS ${status.tick_faults}`);
  $("banner").textContent = alarms.join(" · ");
  $("scrub-at").textContent = page.live ? "live" : (trace ? `at t ${trace.t.toFixed(2)} s` : "");
  $("live").disabled = page.live;
}

const signed = (x) => (x >= 0 ? "+" : "") + Math.round(x);

// The tree to draw: the trace's nodes (every behaviour that ran this tick, remote ones
// included), with the tree service's details (type, priority, weight) where it has them.
function treeOf(trace) {
  if (trace && trace.nodes.length) {
    const root = { children: [] }, stack = [root];
    for (const node of trace.nodes) {
      const item = { ...node, children: [] };
      stack.length = node.depth + 1;
      stack[node.depth].children.push(item);
      stack[node.depth + 1] = item;
    }
    const details = new Map();
    if (page.tree) walk(page.tree.tree, [], (n, path) => details.set(path.join("/"), n));
    walk(root.children[0], [], (n, path) => {
      const d = details.get(path.join("/"));
      if (d) Object.assign(n, { type: d.type, kind: d.kind, priority: d.priority, weight: d.weight });
      if (!n.kind) n.kind = n.children.length ? "composite" : "behavior";
    });
    return withEmptySlots(root.children[0]);
  }
  return page.tree ? withEmptySlots(structuredClone(page.tree.tree)) : null;
}

// A remote behaviour's slot with nobody in it, drawn where it would vote.
function withEmptySlots(tree) {
  for (const slot of (page.tree && page.tree.slots) || []) {
    walk(tree, [], (node) => {
      if (node.name !== slot.composite || !node.children) return;
      if (node.children.some((child) => child.name === slot.name)) return;
      node.children.push({ name: slot.name, kind: "slot", priority: slot.priority,
                           weight: slot.weight, children: [] });
    });
  }
  return tree;
}

function walk(node, path, visit) {
  const here = [...path, node.name];
  visit(node, here);
  for (const child of node.children || []) walk(child, here, visit);
}

function winningLeaves(trace) {
  const out = [];
  if (!trace) return out;
  const nodes = trace.nodes;
  nodes.forEach((node, i) => {
    if (!node.won) return;
    const kids = [];
    for (const n of nodes.slice(i + 1)) {
      if (n.depth <= node.depth) break;
      if (n.depth === node.depth + 1) kids.push(n);
    }
    if (!kids.some((n) => n.won)) out.push(node.name);
  });
  return out;
}

function drawTree(trace) {
  const svg = $("tree");
  const root = treeOf(trace);
  if (!root) { svg.replaceChildren(); return; }
  const winners = new Set(winningLeaves(trace));
  let nextLeaf = 0, deepest = 0;
  (function place(node, depth) {  // leaves side by side; a parent above its children's middle
    deepest = Math.max(deepest, depth);
    node.y = depth * (NODE_H + GAP_Y) + 4;
    const kids = node.children || [];
    if (!kids.length) { node.x = nextLeaf++ * (NODE_W + GAP_X) + 4; return; }
    kids.forEach((k) => place(k, depth + 1));
    node.x = (kids[0].x + kids[kids.length - 1].x) / 2;
  })(root, 0);
  const parts = [];
  walk(root, [], (node, path) => {
    for (const child of node.children || []) {
      const edge = el("path", { class: "edge" + (child.won ? " won" : ""),
        d: `M${node.x + NODE_W / 2},${node.y + NODE_H} C${node.x + NODE_W / 2},${node.y + NODE_H + GAP_Y / 2} ` +
           `${child.x + NODE_W / 2},${child.y - GAP_Y / 2} ${child.x + NODE_W / 2},${child.y}` });
      parts.push(edge);
    }
  });
  walk(root, [], (node, path) => parts.push(nodeBox(node, path, winners)));
  const width = Math.max(nextLeaf * (NODE_W + GAP_X), NODE_W) + 8, height = (deepest + 1) * (NODE_H + GAP_Y);
  svg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  svg.setAttribute("width", String(width));  // natural size, shrunk to the panel if wider
  svg.setAttribute("height", String(height));
  svg.replaceChildren(...parts);
}

function nodeBox(node, path, winners) {
  const leaf = !(node.children || []).length;
  const winner = !!(leaf && node.won && winners.has(node.name));
  const classes = ["node", node.kind || (leaf ? "behavior" : "composite")];
  if (node.won) classes.push("won");
  if (winner) classes.push("winner");
  if (node.fault) classes.push("fault");
  const g = el("g", { class: classes.join(" "), transform: `translate(${node.x},${node.y})`,
    "data-node": node.name, "data-path": path.join("/"), "data-won": String(!!node.won),
    "data-winner": String(winner) });
  const title = el("title", {});
  title.textContent = [path.join("/"), node.type && `type ${node.type}`,
    node.priority != null && `priority ${node.priority}`, node.weight != null && `weight ${node.weight}`,
    node.fault && `fault: ${node.fault}`].filter(Boolean).join("\n");
  g.append(title, el("rect", { width: NODE_W, height: NODE_H, rx: 6 }));
  g.append(text(8, 18, "name", node.name + (node.priority != null ? `  p${node.priority}` : "")));
  let detail;
  if (node.fault) detail = `fault: ${node.fault}`;
  else if (node.kind === "slot") detail = "remote: nobody yet";
  else if (!leaf) detail = `<${node.arbiter || "?"}>`;
  else if (node.vote == null) detail = "no opinion";
  else detail = `v ${node.vote.toFixed(2)}  ${signed(node.speed)}/${signed(node.turn)}`;
  g.append(text(8, 38, "detail", detail.length > 24 ? detail.slice(0, 23) + "…" : detail));
  return g;
}

function el(tag, attrs) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, String(v));
  return node;
}

function text(x, y, cls, content) {
  const t = el("text", { x, y, class: cls });
  t.textContent = content;
  return t;
}

// The strip: a row per behaviour that won in the window, a mark for each tick it won.
function drawStrip(shownTrace) {
  const canvas = $("strip");
  const width = canvas.clientWidth || 600;
  canvas.width = width;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, width, canvas.height);
  if (!page.ticks.length) return;
  const names = [...new Set(page.ticks.flatMap((tick) => tick[3]))].sort();
  const rows = Math.max(names.length, 1), rowH = Math.min(18, (canvas.height - 4) / rows);
  const end = page.ticks[page.ticks.length - 1][1], start = end - page.historyS;
  const x = (t) => ((t - start) / page.historyS) * (width - 90) + 90;
  ctx.font = "11px system-ui, sans-serif";
  names.forEach((name, row) => {
    ctx.fillStyle = "#6b7785";
    ctx.fillText(name, 2, row * rowH + rowH - 4);
  });
  ctx.fillStyle = "#2e9d4f";
  const tickW = Math.max(1, (width - 90) / (page.historyS * 50));
  for (const [, t, , winners] of page.ticks)
    for (const name of winners) ctx.fillRect(x(t), names.indexOf(name) * rowH + 2, tickW, rowH - 4);
  if (!page.live && shownTrace) {
    ctx.strokeStyle = "#1d2733";
    ctx.beginPath();
    ctx.moveTo(x(shownTrace.t), 0);
    ctx.lineTo(x(shownTrace.t), canvas.height);
    ctx.stroke();
  }
}

function drawSources(status) {
  const body = $("sources").tBodies[0];
  if (!status) return;
  body.replaceChildren(...(status.sources || []).map((s) => {
    const tr = document.createElement("tr");
    tr.dataset.source = s.source;
    if (s.stale) tr.className = "stale";
    if (s.departed) tr.className = "departed";
    const age = s.departed ? s.departed.toUpperCase() : `${Math.round(s.age_s * 1000)} ms`;
    tr.append(cell(s.source), cell(age, "age"),
      cell(s.departed ? "" : s.stale ? "STALE" : s.refused ? `refused ${s.refused}` : ""));
    return tr;
  }));
}

function drawState(state) {
  const box = $("state");
  if (!state) return;
  box.replaceChildren(...Object.keys(state).sort().map((source) => {
    const sample = state[source];
    const details = document.createElement("details");
    details.open = page.openState.has(source);
    details.ontoggle = () => details.open ? page.openState.add(source) : page.openState.delete(source);
    const summary = document.createElement("summary");
    summary.textContent = `${source} (${sample.schema}, t ${sample.t.toFixed(2)} s)`;
    const pre = document.createElement("pre");
    pre.textContent = JSON.stringify(sample.data, null, 1);
    details.append(summary, pre);
    return details;
  }));
}

function cell(content, cls) {
  const td = document.createElement("td");
  td.textContent = content;
  if (cls) td.className = cls;
  return td;
}

function option(value, label) {
  const o = document.createElement("option");
  o.value = value;
  o.textContent = label;
  return o;
}

// -- the forms --------------------------------------------------------------------------------

function selectedComposite() {
  let found = null;
  if (page.tree) walk(page.tree.tree, [], (node) => { if (node.name === $("composite").value) found = node; });
  return found;
}

function fillChildren() {
  const composite = selectedComposite();
  const select = $("child");
  const chosen = select.value;
  const kids = composite ? composite.children || [] : [];
  select.replaceChildren(...kids.map((k) => option(k.name, k.name)));
  if (kids.some((k) => k.name === chosen)) select.value = chosen;
  fillChildValues();
  if (composite && document.activeElement !== $("arbiter")) $("arbiter").placeholder = composite.arbiter || "";
}

function fillChildValues() {
  const composite = selectedComposite();
  const child = composite && (composite.children || []).find((k) => k.name === $("child").value);
  if (child) {
    $("priority").placeholder = String(child.priority);
    $("weight").placeholder = String(child.weight);
  }
}

$("composite").addEventListener("change", fillChildren);
$("child").addEventListener("change", fillChildValues);

$("arbiter-form").addEventListener("submit", (event) => {
  event.preventDefault();
  const name = $("arbiter").value.trim(), raw = $("arbiter-params").value.trim();
  let arbiter = name;
  if (raw) {
    try { arbiter = { type: name, params: JSON.parse(raw) }; }
    catch (err) { showReply("refused", `params are not JSON: ${err.message}`); return; }
  }
  send({ op: "set_arbiter", composite: $("composite").value, arbiter });
});

$("child-form").addEventListener("submit", (event) => {
  event.preventDefault();
  const request = { op: "set_child", composite: $("composite").value, child: $("child").value };
  if ($("priority").value !== "") request.priority = Number($("priority").value);
  if ($("weight").value !== "") request.weight = Number($("weight").value);
  send(request);
});

$("load-form").addEventListener("submit", (event) => {
  event.preventDefault();
  send({ op: "load", tree: $("tree-yaml").value });
});

$("scrub").addEventListener("input", () => {
  page.live = Number($("scrub").value) >= page.frames.length - 1;
  render();
});

$("live").addEventListener("click", () => {
  page.live = true;
  $("scrub").value = $("scrub").max;
  render();
});

connect();
