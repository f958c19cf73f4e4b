// sbagents dashboard: every page is an HTML shell whose data comes from /api/ and refreshes while runs write.
"use strict";

const POLL_MS = 2500;
const RUN = document.body.dataset.run;
const $ = (sel) => document.querySelector(sel);

async function getJSON(url) {
  const response = await fetch(url, { cache: "no-store" });
  if (!response.ok) throw new Error(`${response.status} ${url}`);
  return response.json();
}

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v;
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v);
  }
  for (const child of children) node.append(child instanceof Node ? child : String(child ?? ""));
  return node;
}

function fmt(value, digits = 2) {
  if (value === null || value === undefined || value === "") return "";
  if (typeof value === "number") {
    if (Number.isInteger(value)) return value.toLocaleString("en-US");
    return value.toLocaleString("en-US", { maximumFractionDigits: digits, minimumFractionDigits: digits });
  }
  return String(value);
}

function showNotes(notes) {
  const box = $("#notes");
  const unique = [...new Set(notes || [])];
  box.hidden = unique.length === 0;
  box.textContent = unique.join(" ");
}

function markLive(ok) {
  const live = $("#live");
  live.classList.toggle("stale", !ok);
  live.textContent = ok ? `live · ${new Date().toLocaleTimeString()}` : "server unreachable";
}

function every(ms, fn) {
  const tick = async () => {
    try { await fn(); markLive(true); } catch (err) { markLive(false); console.error(err); }
    setTimeout(tick, ms);
  };
  tick();
}

function smooth(values, window) {
  const out = [];
  let sum = 0;
  for (let i = 0; i < values.length; i++) {
    sum += values[i];
    if (i >= window) sum -= values[i - window];
    out.push(sum / Math.min(i + 1, window));
  }
  return out;
}

const PLOT_LAYOUT = { margin: { l: 60, r: 20, t: 30, b: 45 }, legend: { orientation: "h", y: -0.2 }, hovermode: "closest" };
const PLOT_CONFIG = { responsive: true, displaylogo: false };
const COLORS = ["#0969da", "#cf222e", "#1a7f37", "#8250df", "#bc4c00", "#0a7ea4", "#bf3989", "#57606a"];

function evalTraces(ev, name, color) {
  if (!ev.timesteps.length) return [];
  const upper = ev.mean.map((m, i) => m + ev.std[i]);
  const lower = ev.mean.map((m, i) => m - ev.std[i]);
  return [
    { x: ev.timesteps, y: upper, mode: "lines", line: { width: 0 }, hoverinfo: "skip", showlegend: false, name: `${name} +std` },
    { x: ev.timesteps, y: lower, mode: "lines", line: { width: 0 }, fill: "tonexty", fillcolor: color + "33",
      hoverinfo: "skip", name: `${name} ± std over eval episodes` },
    { x: ev.timesteps, y: ev.mean, mode: "lines+markers", line: { color, dash: "dash" }, name: `${name} evaluation (mean)`,
      customdata: ev.min.map((m, i) => [m, ev.max[i], ev.std[i]]),
      hovertemplate: "%{x} steps<br>mean %{y:.2f} ± %{customdata[2]:.2f}<br>min %{customdata[0]:.2f}, max %{customdata[1]:.2f}<extra></extra>" },
  ];
}

// ---- runs ---------------------------------------------------------------------------------------------------------
function runsPage() {
  const selected = new Set();
  let rows = [];
  let sortKey = "started", sortDir = -1;
  const tbody = $("#runs tbody");
  const render = () => {
    const words = $("#filter").value.toLowerCase().split(/\s+/).filter(Boolean);
    const shown = rows.filter((r) => {
      const text = [r.algo, r.env, r.status, r.backend, r.folder, r.seed, r.k].join(" ").toLowerCase();
      return words.every((w) => text.includes(w));
    });
    shown.sort((a, b) => {
      const x = a[sortKey], y = b[sortKey];
      if (x === y) return 0;
      if (x === null || x === undefined) return 1;
      if (y === null || y === undefined) return -1;
      return (x < y ? -1 : 1) * sortDir;
    });
    tbody.replaceChildren(...shown.map((r) => {
      const box = el("input", { type: "checkbox", "data-id": r.id });
      box.checked = selected.has(r.id);
      box.addEventListener("change", () => { box.checked ? selected.add(r.id) : selected.delete(r.id); update(); });
      const link = el("a", { href: `/run/${r.id}` }, r.env);
      const status = el("span", { class: `status ${r.status}` }, r.status);
      if (r.notes.length) status.title = r.notes.join(" ");
      return el("tr", { "data-id": r.id },
        el("td", {}, box), el("td", {}, r.algo), el("td", {}, link), el("td", {}, fmt(r.k)), el("td", {}, fmt(r.seed)),
        el("td", {}, status, r.notes.length ? " ⚠" : ""), el("td", { class: "num" }, fmt(r.steps)),
        el("td", { class: "num" }, fmt(r.fps, 0)), el("td", { class: "num" }, fmt(r.train_seconds, 1)),
        el("td", { class: "num" }, r.eval_return === null ? "" : `${fmt(r.eval_return)} ± ${fmt(r.eval_std)}`),
        el("td", { class: "num" }, fmt(r.success_rate)), el("td", {}, r.backend), el("td", {}, r.folder),
        el("td", {}, r.started ? new Date(r.started * 1000).toLocaleString() : ""));
    }));
    $("#count").textContent = `${shown.length} of ${rows.length} runs`;
  };
  const update = () => { $("#compare").disabled = selected.size === 0; };
  document.querySelectorAll("#runs th[data-key]").forEach((th) => th.addEventListener("click", () => {
    sortDir = sortKey === th.dataset.key ? -sortDir : 1;
    sortKey = th.dataset.key;
    document.querySelectorAll("#runs th").forEach((h) => h.classList.remove("sorted-asc", "sorted-desc"));
    th.classList.add(sortDir > 0 ? "sorted-asc" : "sorted-desc");
    render();
  }));
  $("#filter").addEventListener("input", render);
  $("#compare").addEventListener("click", () => {
    location.href = "/compare?" + [...selected].map((id) => "run=" + encodeURIComponent(id)).join("&");
  });
  every(3000, async () => { rows = (await getJSON("/api/runs")).runs; render(); });
}

// ---- one run ------------------------------------------------------------------------------------------------------
function fileList(files, title) {
  if (!files.length) return [];
  return [el("h3", {}, title), el("ul", { class: "files" }, ...files.map((f) =>
    el("li", {}, el("a", { href: `/file/${RUN}/${f.path}?download=1` }, f.path), ` (${fmt(f.size / 1024, 1)} KiB)`)))];
}

function runPage() {
  let settingsLoaded = false;
  every(POLL_MS, async () => {
    const data = await getJSON(`/api/curves/${RUN}`);
    const run = data.run, train = data.train, ev = data.eval;
    $("#status").textContent = run.status;
    $("#status").className = `status ${run.status}`;
    $("#facts").replaceChildren(...[
      ["steps", fmt(run.steps)], ["episodes", fmt(train.episodes ?? train.returns.length)], ["fps", fmt(run.fps, 0)],
      ["train time", run.train_seconds === null ? "" : `${fmt(run.train_seconds, 1)} s`],
      ["final eval", run.eval_return === null ? "" : `${fmt(run.eval_return)} ± ${fmt(run.eval_std)}`],
      ["success", fmt(run.success_rate)], ["seed", fmt(run.seed)], ["backend", run.backend],
    ].filter(([, v]) => v !== "").map(([k, v]) => el("span", {}, `${k} `, el("b", {}, v))));
    const window = Math.max(1, Math.floor(train.returns.length / 20));
    const traces = [
      { x: train.timesteps, y: train.returns, mode: "markers", marker: { size: 3, color: "#8c959f" },
        name: train.episodes > train.returns.length ? `training episodes (${fmt(train.returns.length)} of ${fmt(train.episodes)})` : "training episodes" },
      { x: train.timesteps, y: smooth(train.returns, window), mode: "lines", line: { color: COLORS[0] },
        name: `training (moving mean of ${window})` },
      ...evalTraces(ev, "", COLORS[1]),
    ];
    Plotly.react("curves", traces, { ...PLOT_LAYOUT, xaxis: { title: { text: "timesteps" } }, yaxis: { title: { text: "episode return" } } }, PLOT_CONFIG);
    const hasSuccess = ev.success.some((s) => s !== null);
    $("#success").hidden = !hasSuccess;
    if (hasSuccess) {
      Plotly.react("success", [{ x: ev.timesteps, y: ev.success, mode: "lines+markers", name: "evaluation success rate" }],
        { ...PLOT_LAYOUT, yaxis: { title: { text: "success rate" }, range: [0, 1.05] }, xaxis: { title: { text: "timesteps" } } }, PLOT_CONFIG);
    }
    const notes = [...data.notes];
    if (!settingsLoaded || run.status === "running") {
      const s = await getJSON(`/api/settings/${RUN}`);
      settingsLoaded = true;
      notes.push(...s.notes);
      $("#command").textContent = s.command || "(no command.txt)";
      $("#args").textContent = s.args ? JSON.stringify(s.args, null, 2) : "(no args.yml)";
      $("#config").textContent = s.config ? JSON.stringify(s.config, null, 2) : "(no config.yml)";
      $("#summary").textContent = s.summary ? JSON.stringify(s.summary, null, 2) : "(no summary.json yet)";
      const f = s.files;
      const logs = s.logs.map((log) => el("li", {}, el("a", { href: `/decisions/${RUN}?log=${encodeURIComponent(log)}` }, log)));
      $("#files").replaceChildren(...fileList(f.models, "Models and outputs"), ...fileList(f.exports, "Exported policy"),
        ...fileList(f.checkpoints, "Checkpoints"), ...(logs.length ? [el("h3", {}, "Decision logs"), el("ul", { class: "files" }, ...logs)] : []));
      if (f.videos.length) {
        $("#videos").replaceChildren(...f.videos.map((v) => el("div", {},
          el("video", { src: `/file/${RUN}/${v.path}`, controls: "", preload: "metadata", muted: "" }),
          el("p", {}, v.path, v.decisions ? " · " : "",
            v.decisions ? el("a", { href: `/decisions/${RUN}?log=${encodeURIComponent(v.decisions)}` }, "its decisions") : ""))));
      }
    }
    showNotes(notes);
  });
}

// ---- decisions ----------------------------------------------------------------------------------------------------
function decisionsPage() {
  const params = new URLSearchParams(location.search);
  const form = $("#filters");
  const state = { start: 0, cursors: [0], count: 50, columns: [], actionCount: null, last: null, loadId: 0, notes: [] };
  const query = () => {
    const q = new URLSearchParams();
    for (const [k, v] of new FormData(form).entries()) if (v !== "") q.set(k, v);
    return q;
  };
  const filtered = () => [...query().keys()].some((k) => k !== "log");
  const violating = (row, cols) => {
    const v = cols.indexOf("violation"), c = cols.indexOf("cost");
    return (v >= 0 && row[v] !== "") || (c >= 0 && parseFloat(row[c]) > 0);
  };
  const render = (page, scanning = false) => {
    state.last = page;
    state.columns = page.columns;
    showNotes([...state.notes, ...(page.notes || [])]);
    $("#decisions thead").replaceChildren(el("tr", {}, el("th", {}, "row"), ...page.columns.map((c) => el("th", {}, c))));
    const epCol = page.columns.findIndex((c) => c.toLowerCase() === "episode");
    const envCol = page.columns.indexOf("env"), agentCol = page.columns.indexOf("agent");
    $("#decisions tbody").replaceChildren(...page.rows.map((row, i) => {
      const tr = el("tr", { class: violating(row, page.columns) ? "violation" : "" }, el("td", { class: "num" }, fmt(page.row_numbers[i])));
      row.forEach((cell, j) => {
        const td = el("td", {}, cell);
        if (j === epCol) {
          td.className = "episode-link";
          td.title = "show this episode's timeline";
          td.addEventListener("click", () => showEpisode(cell, envCol >= 0 ? row[envCol] : "", agentCol >= 0 ? row[agentCol] : ""));
        }
        tr.append(td);
      });
      return tr;
    }));
    const indexing = page.complete ? "" : " (indexing…)";
    if (filtered()) {
      $("#position").textContent = `${page.rows.length} matching rows · scanned ${fmt(page.scanned_to)} of ${fmt(page.total_rows)} rows${indexing}`
        + (scanning ? " · scanning…" : page.next_cursor === null ? " · end of log" : "");
      $("#next").disabled = scanning || page.next_cursor === null;
      $("#prev").disabled = state.cursors.length <= 1;
    } else {
      const first = page.row_numbers.length ? page.row_numbers[0] + 1 : 0;
      const last = page.row_numbers.length ? page.row_numbers[page.row_numbers.length - 1] + 1 : 0;
      $("#position").textContent = `rows ${fmt(first)}–${fmt(last)} of ${fmt(page.total_rows)}${indexing}`;
      $("#prev").disabled = first <= 1;
      $("#next").disabled = page.complete && last >= page.total_rows;
    }
  };
  // A filtered page is filled by further requests from where the server's time-boxed scan stopped (rare matches
  // in a big log), shown as it grows; a newer load (a click, a new filter) ends the older one.
  const load = async (tail = false) => {
    const id = ++state.loadId;
    const q = query();
    q.set("count", state.count);
    if (filtered()) q.set("cursor", state.cursors[state.cursors.length - 1]);
    else if (tail) q.set("tail", "1");
    else q.set("start", state.start);
    let page = await getJSON(`/api/decisions/${RUN}?${q}`);
    while (filtered() && page.rows.length < state.count && page.next_cursor !== null && id === state.loadId) {
      render(page, true);
      q.set("cursor", page.next_cursor);
      q.set("count", state.count - page.rows.length);
      const more = await getJSON(`/api/decisions/${RUN}?${q}`);
      page = { ...more, rows: [...page.rows, ...more.rows], row_numbers: [...page.row_numbers, ...more.row_numbers] };
    }
    if (id !== state.loadId) return;
    if (tail && page.row_numbers.length) state.start = page.row_numbers[0];
    render(page);
  };
  const timelineLayout = (title) => ({
    ...PLOT_LAYOUT, title: { text: title, font: { size: 13 } }, grid: { rows: 3, columns: 1, pattern: "independent" },
    yaxis: { title: { text: "observation" } }, yaxis2: { title: { text: "action" } }, yaxis3: { title: { text: "reward, cost" } },
    xaxis3: { title: { text: "step" } }, legend: { orientation: "v", x: 1.02, y: 1 }, margin: { l: 60, r: 10, t: 30, b: 40 },
  });
  const showEpisode = async (episode, env, agent) => {
    const q = new URLSearchParams({ log: $("#log").value, episode });
    if (env !== "") q.set("env", env);
    if (agent !== "") q.set("agent", agent);
    const data = await getJSON(`/api/episode/${RUN}?${q}`);
    const cols = data.columns, lower = cols.map((c) => c.toLowerCase());
    const stepCol = lower.indexOf("step"), rewardCol = lower.indexOf("reward");
    const costCol = lower.indexOf("cost"), frameCol = lower.indexOf("frame");
    const steps = data.rows.map((r) => Number(r[stepCol]));
    const decision = cols.slice(stepCol + 1, rewardCol).map((name, i) => [name, stepCol + 1 + i]);
    const nAct = state.actionCount ?? 0;
    const traces = [];
    decision.forEach(([name, j], i) => {
      const isAction = i >= decision.length - nAct;
      const values = data.rows.map((r) => Number(r[j]));
      if (values.some(Number.isNaN)) return;
      traces.push({ x: steps, y: values, name, mode: "lines", xaxis: isAction ? "x2" : "x", yaxis: isAction ? "y2" : "y",
        visible: !isAction && i >= 8 ? "legendonly" : true });
    });
    traces.push({ x: steps, y: data.rows.map((r) => Number(r[rewardCol])), name: "reward", mode: "lines", xaxis: "x3", yaxis: "y3" });
    if (costCol >= 0) traces.push({ x: steps, y: data.rows.map((r) => Number(r[costCol])), name: "cost", mode: "lines", xaxis: "x3", yaxis: "y3", line: { color: "#cf222e" } });
    const title = `episode ${episode}` + (env !== "" ? `, env ${env}` : "") + (agent ? `, ${agent}` : "")
      + ` · ${data.rows.length} decisions` + (nAct ? "" : " (actions not told apart: no model zip)");
    $("#episode").hidden = false;
    $("#episode-title").textContent = title;
    await Plotly.react("timeline", traces, timelineLayout(""), PLOT_CONFIG);
    const video = $("#video");
    if (data.video && frameCol >= 0) {
      const frames = data.rows.map((r) => Number(r[frameCol]));
      video.hidden = false;
      if (!video.src.endsWith(data.video)) video.src = `/file/${RUN}/${data.video}`;
      const seek = (k) => {
        const total = Number(video.dataset.frames || 0) || 0;
        if (video.duration && total) video.currentTime = (frames[k] + 0.5) * video.duration / total;
        $("#frame-note").textContent = `frame ${frames[k]} · step ${steps[k]}`;
      };
      const totals = await getJSON(`/api/decisions/${RUN}?log=${encodeURIComponent($("#log").value)}&tail=1&count=1`);
      video.dataset.frames = String((Number(totals.rows[0]?.[frameCol] ?? 0) + 2));
      const seekWhenReady = (k) => (video.readyState >= 1 ? seek(k) : video.addEventListener("loadedmetadata", () => seek(k), { once: true }));
      seekWhenReady(0);
      const chart = $("#timeline");
      chart.removeAllListeners?.("plotly_hover");
      chart.on("plotly_hover", (ev) => seekWhenReady(Math.max(0, steps.indexOf(ev.points[0].x))));
      chart.on("plotly_click", (ev) => seekWhenReady(Math.max(0, steps.indexOf(ev.points[0].x))));
    } else {
      video.hidden = true;
      $("#frame-note").textContent = "No video for this log: the decisions recorded with python -m sbagents.record_video "
        + "(videos/*.csv) show each step's frame.";
    }
    $("#episode").scrollIntoView({ behavior: "smooth" });
  };
  form.addEventListener("submit", (e) => { e.preventDefault(); state.start = 0; state.cursors = [0]; load(); });
  $("#violations").addEventListener("change", () => { state.cursors = [0]; state.start = 0; load(); });
  $("#log").addEventListener("change", () => { state.cursors = [0]; state.start = 0; load(); });
  $("#next").addEventListener("click", () => {
    if (filtered()) state.cursors.push(state.last.next_cursor);
    else state.start += state.count;
    load();
  });
  $("#prev").addEventListener("click", () => {
    if (filtered()) state.cursors.pop();
    else state.start = Math.max(0, state.start - state.count);
    load();
  });
  (async () => {
    const settings = await getJSON(`/api/settings/${RUN}`);
    state.actionCount = settings.action_count;
    state.notes = settings.notes;
    showNotes(settings.notes);
    if (!settings.logs.length) {
      $("#position").textContent = "This run has no transparency log (train with --transparency-log).";
      return;
    }
    $("#log").replaceChildren(...settings.logs.map((l) => el("option", { value: l }, l)));
    if (params.get("log") && settings.logs.includes(params.get("log"))) $("#log").value = params.get("log");
    for (const key of ["episode", "env", "agent", "step_min", "step_max", "reward_min", "reward_max"]) {
      if (params.get(key)) form.elements[key].value = params.get(key);
    }
    if (params.get("violations") === "1") $("#violations").checked = true;
    if (params.get("follow") === "1") $("#follow").checked = true;
    every(POLL_MS, () => load($("#follow").checked && !filtered()));
  })();
}

// ---- trust --------------------------------------------------------------------------------------------------------
function trustPage() {
  let advStep = null;
  every(4000, async () => {
    const data = await getJSON(`/api/trust/${RUN}`);
    showNotes(data.notes);
    if (data.safety.length) {
      $("#safety").replaceChildren(...data.safety.map((s) => {
        const types = Object.entries(s.violations || {}).map(([k, v]) => `${k}: ${fmt(v)}`).join(", ") || "none";
        const ep = s.ep_cost || {};
        return el("table", { class: "grid" },
          el("tr", {}, el("th", {}, s.file), el("th", {}, "")),
          ...[["violation steps", `${fmt(s.total_violations)} of ${fmt(s.total_steps)} steps (${fmt(1000 * (s.violation_rate || 0))} per 1,000)`],
            ["by rule", types], ["episodes", fmt(s.episodes)],
            ["EpCost", `mean ${fmt(ep.mean)}, std ${fmt(ep.std)}, max ${fmt(ep.max)}, last ${fmt(ep.window)} episodes ${fmt(ep.last_window_mean)}`],
            ["cost limit", s.cost_limit === null ? "none" : fmt(s.cost_limit)],
            ["stopped", s.stopped ? `yes: ${s.stop_reason}` : "no"],
            ...(s.constraint ? [["constraint", `${s.constraint.method}, limit ${fmt(s.constraint.cost_limit)}, multiplier ${fmt(s.constraint.multiplier)}, last episode cost ${fmt(s.constraint.last_ep_cost)}`]] : [])].map(([k, v]) => el("tr", {}, el("td", {}, k), el("td", {}, v))));
      }));
    }
    drawConstraint(data.safety.find((s) => s.constraint && Array.isArray(s.constraint.history)));
    const costs = data.ep_cost;
    if (costs && costs.has_cost && costs.episodes.length) {
      const w = Math.max(1, Math.floor(costs.episodes.length / 20));
      Plotly.react("epcost", [
        { x: costs.episodes, y: costs.ep_cost, mode: "markers", marker: { size: 3, color: "#8c959f" }, name: "EpCost" },
        { x: costs.episodes, y: smooth(costs.ep_cost, w), mode: "lines", line: { color: "#cf222e" }, name: `moving mean of ${w}` },
      ], { ...PLOT_LAYOUT, title: { text: `EpCost per training episode (${data.ep_cost_log}${costs.progress < 1 ? `, ${fmt(100 * costs.progress, 0)}% read` : ""})`, font: { size: 13 } },
        xaxis: { title: { text: "training episode" } }, yaxis: { title: { text: "episode cost" } } }, PLOT_CONFIG);
    } else {
      $("#epcost").replaceChildren(el("p", { class: "muted" }, data.ep_cost_log
        ? "The transparency log has no cost or violation column." : "EpCost over time needs a transparency log (--transparency-log) of an env with costs."));
      $("#epcost").style.height = "auto";
    }
    const adv = data.adversarial;
    $("#adversarial-none").hidden = adv.timesteps.length > 0;
    if (adv.timesteps.length) {
      const select = $("#adv-step");
      if (select.options.length !== adv.timesteps.length) {
        select.replaceChildren(...adv.timesteps.map((t) => el("option", { value: t }, fmt(Number(t)))));
        select.value = advStep ?? adv.timesteps[adv.timesteps.length - 1];
        select.onchange = () => { advStep = select.value; drawAdversarial(adv, select.value); };
      }
      drawAdversarial(adv, select.value);
    }
    drawFairness(data.fairness);
  });
}

// A constrained run's (--constraint) multiplier and measured episode cost per update, against its cost limit.
function drawConstraint(safety) {
  const box = $("#constraint");
  box.hidden = !safety;
  if (!safety) return;
  const c = safety.constraint, t = c.history.map((h) => h.timesteps);
  Plotly.react("constraint", [
    { x: t, y: c.history.map((h) => h.ep_cost), mode: "lines+markers", marker: { size: 3 }, line: { color: "#cf222e" }, name: "EpCost" },
    { x: [t[0], t[t.length - 1]], y: [c.cost_limit, c.cost_limit], mode: "lines", line: { color: "#cf222e", dash: "dash" }, name: "cost limit" },
    { x: t, y: c.history.map((h) => h.multiplier), mode: "lines", line: { color: "#0969da" }, name: "multiplier", yaxis: "y2" },
  ], { ...PLOT_LAYOUT, margin: { ...PLOT_LAYOUT.margin, r: 60 }, title: { text: `${c.method} constraint: episode cost and multiplier per update (final multiplier ${fmt(c.multiplier)})`, font: { size: 13 } },
    xaxis: { title: { text: "timesteps" } }, yaxis: { title: { text: "episode cost" }, rangemode: "tozero" },
    yaxis2: { title: { text: "multiplier" }, overlaying: "y", side: "right", rangemode: "tozero" } }, PLOT_CONFIG);
}

function drawAdversarial(adv, step) {
  const curves = adv.curves[step] || {};
  const names = Object.keys(curves);
  Plotly.react("adversarial", names.map((name, i) => ({
    x: curves[name].eps, y: curves[name].mean_return, name, mode: "lines+markers", line: { color: COLORS[i % COLORS.length] },
    error_y: { type: "data", array: curves[name].std_return, visible: true, thickness: 1 },
  })), { ...PLOT_LAYOUT, title: { text: "return vs attack strength (± std over episodes)", font: { size: 13 } },
    xaxis: { title: { text: "eps" } }, yaxis: { title: { text: "mean return" } } }, PLOT_CONFIG);
  Plotly.react("adversarial-success", names.map((name, i) => ({
    x: curves[name].eps, y: curves[name].success_rate, name, mode: "lines+markers", line: { color: COLORS[i % COLORS.length] },
  })), { ...PLOT_LAYOUT, title: { text: "success rate vs attack strength", font: { size: 13 } },
    xaxis: { title: { text: "eps" } }, yaxis: { title: { text: "success rate" }, range: [0, 1.05] } }, PLOT_CONFIG);
}

function drawFairness(fair) {
  $("#fairness-none").hidden = Boolean(fair);
  if (!fair) { $("#fairness").style.display = "none"; return; }
  const range = (r) => `${fmt(r[0])}–${fmt(r[1])}`;
  const ci = (b) => `${fmt(b.ci[0])}–${fmt(b.ci[1])}`;
  if (fair.keys.length === 2) {
    const xs = [...new Set(fair.buckets.map((b) => range(b.ranges[0])))];
    const ys = [...new Set(fair.buckets.map((b) => range(b.ranges[1])))];
    const z = ys.map(() => xs.map(() => null)), text = ys.map(() => xs.map(() => ""));
    for (const b of fair.buckets) {
      const i = ys.indexOf(range(b.ranges[1])), j = xs.indexOf(range(b.ranges[0]));
      z[i][j] = b.value;
      text[i][j] = `${fmt(b.value)}<br>[${ci(b)}]<br>n=${fmt(b.n)}`;
    }
    Plotly.react("fairness", [{ type: "heatmap", x: xs, y: ys, z, text, texttemplate: "%{text}", colorscale: [[0, "#cf222e"], [0.5, "#f2cc60"], [1, "#2da44e"]],
      ...(fair.metric.endsWith("rate") ? { zmin: 0, zmax: 1 } : {}),
      hovertemplate: `${fair.keys[0]} %{x}<br>${fair.keys[1]} %{y}<br>${fair.metric} %{z:.2f}<extra></extra>` }],
    { ...PLOT_LAYOUT, title: { text: `${fair.metric} by bucket (95% interval, episodes)`, font: { size: 13 } },
      xaxis: { title: { text: fair.keys[0] } }, yaxis: { title: { text: fair.keys[1] } } }, PLOT_CONFIG);
  } else {
    const b = fair.buckets;
    Plotly.react("fairness", [{ type: "bar", x: b.map((x) => range(x.ranges[0])), y: b.map((x) => x.value),
      text: b.map((x) => `n=${fmt(x.n)}`), name: fair.metric,
      error_y: { type: "data", symmetric: false, array: b.map((x) => (x.ci[1] ?? x.value) - x.value),
        arrayminus: b.map((x) => x.value - (x.ci[0] ?? x.value)) } }],
    { ...PLOT_LAYOUT, title: { text: `${fair.metric} by ${fair.keys[0]} (95% interval)`, font: { size: 13 } },
      xaxis: { title: { text: fair.keys[0] } }, yaxis: { title: { text: fair.metric } } }, PLOT_CONFIG);
  }
}

// ---- compare ------------------------------------------------------------------------------------------------------
function interpolate(grid, xs, ys) {
  return grid.map((g) => {
    if (g <= xs[0]) return ys[0];
    let i = 1;
    while (i < xs.length && xs[i] < g) i++;
    if (i >= xs.length) return ys[ys.length - 1];
    const t = (g - xs[i - 1]) / (xs[i] - xs[i - 1] || 1);
    return ys[i - 1] + t * (ys[i] - ys[i - 1]);
  });
}

function comparePage() {
  const ids = JSON.parse($("#run-ids").textContent);
  const draw = (runs) => {
    const xAxis = $("#x-axis").value, windowArg = Number($("#window").value) || 0, group = $("#group").checked;
    const envs = [...new Set(runs.map((r) => r.run.env))];
    const algos = [...new Set(runs.map((r) => r.run.algo))];
    const box = $("#compare-charts");
    box.replaceChildren(...envs.map((_, i) => el("div", { class: "chart", id: `cmp-${i}` })));
    envs.forEach((env, i) => {
      const traces = [];
      const mine = runs.filter((r) => r.run.env === env);
      for (const algo of algos) {
        const members = mine.filter((r) => r.run.algo === algo && r.train.returns.length);
        const color = COLORS[algos.indexOf(algo) % COLORS.length];
        const series = members.map((r) => {
          const w = windowArg || Math.max(1, Math.floor(r.train.returns.length / 20));
          const x = xAxis === "timesteps" ? r.train.timesteps : r.train.returns.map((_, k) => k + 1);
          return { x, y: smooth(r.train.returns, w), label: `${algo} #${r.run.k ?? ""}` };
        });
        if (group && series.length > 1) {
          const end = Math.min(...series.map((s) => s.x[s.x.length - 1])), start = Math.max(...series.map((s) => s.x[0]));
          const grid = Array.from({ length: 200 }, (_, k) => start + (end - start) * k / 199);
          const stacked = series.map((s) => interpolate(grid, s.x, s.y));
          const mean = grid.map((_, k) => stacked.reduce((a, s) => a + s[k], 0) / stacked.length);
          traces.push({ x: grid, y: grid.map((_, k) => Math.max(...stacked.map((s) => s[k]))), mode: "lines", line: { width: 0 }, showlegend: false, hoverinfo: "skip" });
          traces.push({ x: grid, y: grid.map((_, k) => Math.min(...stacked.map((s) => s[k]))), mode: "lines", line: { width: 0 }, fill: "tonexty", fillcolor: color + "33", name: `${algo} min-max of ${series.length} runs` });
          traces.push({ x: grid, y: mean, mode: "lines", line: { color }, name: `${algo} training (mean of ${series.length})` });
        } else {
          series.forEach((s) => traces.push({ x: s.x, y: s.y, mode: "lines", line: { color }, name: `${s.label} training` }));
        }
        const evals = mine.filter((r) => r.run.algo === algo && r.eval.timesteps.length);
        if (xAxis === "timesteps" && group && evals.length > 1) {  // mean over seeds of each evaluation's mean
          const n = Math.min(...evals.map((r) => r.eval.timesteps.length));
          const at = (k, f) => evals.map((r) => f(r.eval, k));
          const x = Array.from({ length: n }, (_, k) => at(k, (e, j) => e.timesteps[j]).reduce((a, b) => a + b) / evals.length);
          const y = Array.from({ length: n }, (_, k) => at(k, (e, j) => e.mean[j]).reduce((a, b) => a + b) / evals.length);
          traces.push({ x, y, mode: "lines+markers", line: { color, dash: "dash" }, name: `${algo} evaluation (mean of ${evals.length})` });
        } else if (xAxis === "timesteps") {
          evals.forEach((r) => traces.push(...evalTraces(r.eval, `${algo} #${r.run.k ?? ""}`, color).slice(2)));
        }
      }
      Plotly.react(`cmp-${i}`, traces, { ...PLOT_LAYOUT, title: { text: env, font: { size: 14 } },
        xaxis: { title: { text: xAxis === "timesteps" ? "timesteps" : "training episodes" } }, yaxis: { title: { text: "episode return" } } }, PLOT_CONFIG);
    });
    showNotes(runs.flatMap((r) => r.notes));
  };
  let latest = [];
  for (const id of ["#x-axis", "#window", "#group"]) $(id).addEventListener("change", () => draw(latest));
  if (!ids.length) { $("#compare-charts").textContent = "Pick runs on the runs page (checkboxes), then Compare."; return; }
  every(5000, async () => {
    latest = (await getJSON("/api/compare?" + ids.map((id) => "run=" + encodeURIComponent(id)).join("&"))).runs;
    draw(latest);
  });
}

const PAGES = { runs: runsPage, run: runPage, decisions: decisionsPage, trust: trustPage, compare: comparePage };
PAGES[document.body.dataset.page]?.();
