// The run replay page: a time slider over the recorded streams, the behaviour tree with each
// node's status at that moment, a top-down map per floor and the list of events.
// Data comes embedded in the page (#amslam-data); in live mode new lines are polled from the
// server that serves the page (amslam view RUN --serve).
"use strict";

(function () {
  const T = window.AmslamTimeline;
  const STATUS_COLOUR = { SUCCESS: "#2e9d4a", FAILURE: "#d23b3b", RUNNING: "#2f7dd1", INVALID: "#b4bac2" };
  const TRAJ = {
    ground_truth: { colour: "#1f9e5a", label: "ground truth", width: 2.0 },
    vio: { colour: "#e0453a", label: "VIO", width: 1.4 },
    slam: { colour: "#3568d4", label: "SLAM", width: 1.4 },
  };
  const TOUR_COLOUR = "#f08c00";
  const SLC_COLOUR = "#8e3fd6";
  const EVENT_KIND = {
    replan: "plan", planner_tour: "plan", planner_error: "problem",
    loop_closure: "slc", slam_loop_closure: "slc",
    goal_done: "goal", unreachable: "goal",
    crash: "problem", sim_crash: "problem", error: "problem", summary_failed: "problem",
    observer_failed: "problem", metrics_not_written: "problem", land_failed: "problem",
    close_failed: "problem", aborted: "problem",
  };
  const COMPOSITE_GLYPH = { Sequence: "→", Selector: "?", Parallel: "⇉" };

  const data = JSON.parse(document.getElementById("amslam-data").textContent);
  const live = data.live || null;
  const $ = (id) => document.getElementById(id);

  const state = {
    t: 0,
    end: 0,
    playing: false,
    speed: 10,
    follow: !!live,
    finished: !live || !!(data.static && live.finished),
    timeline: new T.TreeTimeline(data.structure || [], data.tree || []),
    events: data.events || [],
    eventTimes: [],
    traj: data.traj || {},
    trajTimes: {},
    stat: data.static || null,
    info: data.info || {},
    bounds: null,
    floorCanvases: [],
    rows: {},
    eventRows: [],
  };

  // -- helpers -------------------------------------------------------------------------------------

  function esc(s) {
    // every string from a run folder that goes into markup goes through here: a crafted run folder
    // must not run script in the page
    return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
  }

  function fmt(x, digits) {
    return typeof x === "number" ? x.toFixed(digits === undefined ? 2 : digits) : String(x);
  }

  function short(value, limit) {
    let s = typeof value === "string" ? value : JSON.stringify(value);
    if (s === undefined) s = "";
    return s.length > limit ? s.slice(0, limit - 1) + "…" : s;
  }

  function refreshTimes() {
    for (const name in state.traj) state.trajTimes[name] = state.traj[name].map((p) => p[0]);
    let end = 0;
    const tl = state.timeline.times;
    if (tl.length) end = Math.max(end, tl[tl.length - 1]);
    if (state.events.length) end = Math.max(end, state.events[state.events.length - 1].t || 0);
    for (const name in state.traj) {
      const tr = state.traj[name];
      if (tr.length) end = Math.max(end, tr[tr.length - 1][0]);
    }
    state.end = end;
    const slider = $("slider");
    slider.max = String(end);
    $("t-end").textContent = fmt(end, 1);
  }

  function floors() {
    if (state.stat && state.stat.floors && state.stat.floors.length) return state.stat.floors;
    const heights = state.info.floor_heights && state.info.floor_heights.length ? state.info.floor_heights : [null];
    return heights.map((lo, i) => ({ lo: lo, hi: i + 1 < heights.length ? heights[i + 1] : null, cells: [] }));
  }

  function floorOf(z) {
    const fl = floors();
    for (let i = fl.length - 1; i >= 0; i--) if (fl[i].lo === null || z >= fl[i].lo) return i;
    return 0;
  }

  // a class's colour comes with the run's summaries (amslam.lib.class_colours): the simulator's,
  // rerun's and the report's colour of that class
  function classColour(name) {
    return ((state.stat && state.stat.class_colours) || {})[name] || "#888888";
  }

  // -- header --------------------------------------------------------------------------------------

  function renderHeader() {
    const info = state.info;
    const m = (state.stat && state.stat.metrics) || {};
    $("title").textContent = (info.mission || "run") + " · " + (info.folder || "");
    const verdict = m.verdict || (state.finished ? "finished" : "in progress");
    const badge = $("verdict");
    badge.textContent = verdict;
    badge.className = "badge " + (verdict === "completed" ? "ok" : verdict === "in progress" ? "live" : "bad");
    const facts = [];
    if (info.plugins) facts.push(Object.entries(info.plugins).map(([k, v]) => k + "=" + v).join(" "));
    if (m.explored_percent !== undefined) facts.push("explored " + m.explored_percent + " %");
    if (m.distance_m !== undefined) facts.push(fmt(m.distance_m, 1) + " m flown");
    if (m.landmarks) facts.push(m.landmarks.count + " landmarks");
    if (m.final_error) facts.push("final error VIO " + m.final_error.vio_position_m + " m / SLAM " + m.final_error.slam_position_m + " m");
    $("facts").textContent = facts.join(" · ");
  }

  // -- the tree ------------------------------------------------------------------------------------

  function buildTree() {
    const container = $("tree");
    container.innerHTML = "";
    state.rows = {};
    const children = {};
    for (const node of state.timeline.structure) {
      const key = node.parent === null ? "root" : String(node.parent);
      (children[key] = children[key] || []).push(node);
    }
    const walk = (node, depth) => {
      const row = document.createElement("div");
      row.className = "node";
      row.dataset.nodeId = String(node.id);
      row.dataset.name = node.name;
      row.style.paddingLeft = 6 + depth * 16 + "px";
      const glyph = COMPOSITE_GLYPH[node.type] || (children[String(node.id)] ? "◇" : "");
      row.title = node.type;
      row.innerHTML =
        '<span class="dot"></span><span class="glyph">' + esc(glyph) + '</span><span class="name">' +
        esc(node.name) + '</span><span class="status"></span><span class="fb"></span>';
      container.appendChild(row);
      state.rows[node.id] = row;
      for (const child of children[String(node.id)] || []) walk(child, depth + 1);
    };
    for (const rootNode of children.root || []) walk(rootNode, 0);
  }

  function renderTree(s) {
    const changed = s.index > 0 ? state.timeline.records[s.index - 1] : null;
    const fresh = changed && Math.abs(changed[0] - state.t) < 0.051 ? changed[2] : {};
    for (const id in state.rows) {
      const row = state.rows[id];
      const v = s.nodes[id] || [T.INVALID, ""];
      if (row.dataset.status !== v[0]) {
        row.dataset.status = v[0];
        row.querySelector(".dot").style.background = STATUS_COLOUR[v[0]] || "#888";
        row.querySelector(".status").textContent = v[0] === T.INVALID ? "" : v[0].toLowerCase();
      }
      // an INVALID node keeps the message of its last run (py_trees does not clear it): say so
      row.querySelector(".fb").textContent = v[1] ? (v[0] === T.INVALID ? "last: " + v[1] : v[1]) : "";
      row.classList.toggle("fresh", id in fresh);
    }
    $("tick").textContent = "tick " + s.tick + " · " + s.index + "/" + state.timeline.records.length + " changes";
    const bb = $("blackboard");
    const keys = Object.keys(s.bb).sort();
    bb.innerHTML = keys
      .map((k) => '<div class="bbrow"><span class="key">' + esc(k) + '</span><span class="val">' +
        esc(short(s.bb[k], 160)) + "</span></div>")
      .join("");
  }

  // -- the map -------------------------------------------------------------------------------------

  function computeBounds() {
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    const add = (x, y) => {
      if (x < x0) x0 = x;
      if (x > x1) x1 = x;
      if (y < y0) y0 = y;
      if (y > y1) y1 = y;
    };
    for (const f of floors()) for (const c of f.cells) add(c[0], c[1]);
    for (const name in state.traj) for (const p of state.traj[name]) add(p[1], p[2]);
    for (const e of state.events) if (e.event === "replan") for (const s of e.tour || []) add(s[1], s[2]);
    if (state.stat) for (const lm of state.stat.landmarks || []) add(lm.p[0], lm.p[1]);
    if (!isFinite(x0)) { x0 = -5; y0 = -5; x1 = 5; y1 = 5; }
    const m = 0.6;
    state.bounds = { x0: x0 - m, y0: y0 - m, x1: x1 + m, y1: y1 + m };
  }

  function buildMaps() {
    computeBounds();
    renderLegend(); // first: the maps get the height it leaves
    const container = $("maps");
    container.innerHTML = "";
    state.floorCanvases = [];
    const fl = floors();
    container.classList.toggle("multi", fl.length > 1);
    const b = state.bounds;
    const aspect = (b.y1 - b.y0) / (b.x1 - b.x0);
    const cols = fl.length > 1 ? 2 : 1;
    const rows = Math.ceil(fl.length / cols);
    // fit the panel: its width, and its height left under the title and above the legend
    const panel = container.parentElement;
    const free = panel.clientHeight - (container.offsetTop - panel.offsetTop) - $("legend").offsetHeight - 24;
    const maxHeight = Math.max(200, free / rows - 22);
    let width = Math.max(240, Math.floor((container.clientWidth - 12 * (cols - 1)) / cols) - 4);
    let height = Math.round(width * aspect);
    if (height > maxHeight) {
      height = Math.round(maxHeight);
      width = Math.round(Math.min(width, height / aspect));
    }
    fl.forEach((f, i) => {
      const box = document.createElement("div");
      box.className = "floor";
      const per = (state.stat && state.stat.metrics && state.stat.metrics.explored_percent_per_floor) || [];
      const range = f.lo === null ? "" : " · z " + fmt(f.lo, 1) + (f.hi !== null ? "–" + fmt(f.hi, 1) : "+") + " m";
      const explored = per[i] !== undefined && per[i] !== null ? " · explored " + per[i] + " %" : "";
      const title = document.createElement("div");
      title.className = "floor-title";
      title.textContent = "floor " + i + range + explored;
      box.appendChild(title);
      const canvas = document.createElement("canvas");
      canvas.id = "floor-" + i;
      const dpr = window.devicePixelRatio || 1;
      canvas.width = Math.round(width * dpr);
      canvas.height = Math.round(height * dpr);
      canvas.style.width = width + "px";
      canvas.style.height = height + "px";
      box.appendChild(canvas);
      container.appendChild(box);
      const scale = Math.min(width / (b.x1 - b.x0), height / (b.y1 - b.y0));
      const ox = (width - scale * (b.x1 - b.x0)) / 2;
      const oy = (height - scale * (b.y1 - b.y0)) / 2;
      const view = {
        canvas, dpr, width, height, scale,
        X: (x) => ox + (x - b.x0) * scale,
        Y: (y) => height - oy - (y - b.y0) * scale, // north up
      };
      view.background = drawBackground(f, view);
      state.floorCanvases.push(view);
    });
  }

  function drawBackground(f, view) {
    const bg = document.createElement("canvas");
    bg.width = view.canvas.width;
    bg.height = view.canvas.height;
    const g = bg.getContext("2d");
    g.scale(view.dpr, view.dpr);
    g.fillStyle = "#fbfbfc";
    g.fillRect(0, 0, view.width, view.height);
    // a 1 m grid
    const b = state.bounds;
    g.strokeStyle = "#eceef1";
    g.lineWidth = 1;
    g.beginPath();
    for (let x = Math.ceil(b.x0); x <= b.x1; x++) { g.moveTo(view.X(x), 0); g.lineTo(view.X(x), view.height); }
    for (let y = Math.ceil(b.y0); y <= b.y1; y++) { g.moveTo(0, view.Y(y)); g.lineTo(view.width, view.Y(y)); }
    g.stroke();
    const v = (state.stat && state.stat.voxel) || 0.25;
    const size = Math.max(1, v * view.scale);
    let most = 1;
    for (const c of f.cells) most = Math.max(most, c[2]);
    for (const c of f.cells) {
      // tall columns are walls (dark), short ones furniture or clutter (lighter)
      const k = Math.min(1, c[2] / Math.max(3, 0.6 * most));
      const shade = Math.round(190 - 130 * k);
      g.fillStyle = "rgb(" + shade + "," + (shade + 4) + "," + (shade + 10) + ")";
      g.fillRect(view.X(c[0]) - size / 2, view.Y(c[1]) - size / 2, size, size);
    }
    // scale bar
    g.fillStyle = "#444";
    g.fillRect(12, view.height - 14, view.scale, 3);
    g.font = "11px sans-serif";
    g.fillText("1 m", 14 + view.scale, view.height - 10);
    return bg;
  }

  function renderLegend() {
    const items = [];
    for (const name in TRAJ) {
      if (state.traj[name] && state.traj[name].length) {
        items.push('<span><i class="line" style="background:' + TRAJ[name].colour + '"></i>' + TRAJ[name].label + "</span>");
      }
    }
    items.push('<span><i class="tri"></i>robot</span>');
    items.push('<span><i class="ring" style="border-color:' + TOUR_COLOUR + '"></i>tour stop</span>');
    items.push('<span><i class="diamond" style="border-color:' + SLC_COLOUR + '"></i>SLC viewpoint</span>');
    const counts = {};
    for (const lm of (state.stat && state.stat.landmarks) || []) counts[lm.class] = (counts[lm.class] || 0) + 1;
    for (const cls of Object.keys(counts).sort()) {
      items.push('<span><i class="disc" style="background:' + classColour(cls) + '"></i>' + esc(cls) + " ×" + counts[cls] + "</span>");
    }
    if (!state.stat) items.push('<span class="muted">map and landmarks appear when the run ends</span>');
    $("legend").innerHTML = items.join("");
  }

  function drawPath(g, view, points, floorIndex, until, style) {
    g.strokeStyle = style.colour;
    g.lineWidth = style.width;
    g.beginPath();
    let pen = false;
    for (const p of points) {
      if (p[0] > until) break;
      if (floorOf(p[3]) !== floorIndex) { pen = false; continue; }
      const x = view.X(p[1]), y = view.Y(p[2]);
      if (pen) g.lineTo(x, y);
      else g.moveTo(x, y);
      pen = true;
    }
    g.stroke();
  }

  function drawRobot(g, view, pose, fill, stroke, size) {
    const x = view.X(pose[0]), y = view.Y(pose[1]);
    const a = -pose[3]; // canvas y points down
    g.save();
    g.translate(x, y);
    g.rotate(a);
    g.beginPath();
    g.moveTo(size, 0);
    g.lineTo(-size * 0.65, size * 0.6);
    g.lineTo(-size * 0.35, 0);
    g.lineTo(-size * 0.65, -size * 0.6);
    g.closePath();
    if (fill) { g.fillStyle = fill; g.fill(); }
    g.strokeStyle = stroke;
    g.lineWidth = 1.6;
    g.stroke();
    g.restore();
  }

  function drawDiamond(g, x, y, r, colour, filled) {
    g.beginPath();
    g.moveTo(x, y - r); g.lineTo(x + r, y); g.lineTo(x, y + r); g.lineTo(x - r, y); g.closePath();
    if (filled) { g.fillStyle = colour; g.fill(); }
    g.strokeStyle = colour;
    g.lineWidth = 1.6;
    g.stroke();
  }

  function drawCross(g, x, y, r, colour) {
    g.strokeStyle = colour;
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(x - r, y - r); g.lineTo(x + r, y + r); g.moveTo(x + r, y - r); g.lineTo(x - r, y + r);
    g.stroke();
  }

  function renderMaps(robot) {
    const t = state.t;
    const tour = T.tourAt(state.events, t);
    const slcs = T.slcViewpointsUntil(state.events, t);
    const estimates = {};
    for (const name of ["vio", "slam"]) {
      if (state.traj[name] && state.traj[name].length) estimates[name] = T.poseAt(state.traj[name], t, state.trajTimes[name]);
    }
    state.floorCanvases.forEach((view, fi) => {
      const g = view.canvas.getContext("2d");
      g.setTransform(1, 0, 0, 1, 0, 0);
      g.drawImage(view.background, 0, 0);
      g.setTransform(view.dpr, 0, 0, view.dpr, 0, 0);
      g.lineJoin = "round";
      g.lineCap = "round";
      // goals reached / given up so far
      for (const e of state.events) {
        if (e.t > t) break;
        if ((e.event === "goal_done" || e.event === "unreachable") && e.goal && floorOf(e.goal[2]) === fi) {
          const x = view.X(e.goal[0]), y = view.Y(e.goal[1]);
          if (e.event === "goal_done") {
            g.fillStyle = "rgba(31,158,90,0.35)";
            g.beginPath(); g.arc(x, y, 3, 0, 2 * Math.PI); g.fill();
          } else drawCross(g, x, y, 3, "rgba(210,59,59,0.6)");
        }
      }
      for (const name of ["ground_truth", "slam", "vio"]) {
        if (state.traj[name]) drawPath(g, view, state.traj[name], fi, t, TRAJ[name]);
      }
      // SLC viewpoints any tour held so far
      for (const p of slcs) if (floorOf(p[2]) === fi) drawDiamond(g, view.X(p[0]), view.Y(p[1]), 5, SLC_COLOUR, false);
      // the current tour: from the robot through its stops
      if (tour.length) {
        g.setLineDash([5, 4]);
        g.strokeStyle = TOUR_COLOUR;
        g.lineWidth = 1.5;
        g.beginPath();
        let started = false;
        if (robot && floorOf(robot[2]) === fi) { g.moveTo(view.X(robot[0]), view.Y(robot[1])); started = true; }
        for (const s of tour) {
          if (floorOf(s[3]) !== fi) continue;
          if (started) g.lineTo(view.X(s[1]), view.Y(s[2]));
          else { g.moveTo(view.X(s[1]), view.Y(s[2])); started = true; }
        }
        g.stroke();
        g.setLineDash([]);
        tour.forEach((s, i) => {
          if (floorOf(s[3]) !== fi) return;
          const x = view.X(s[1]), y = view.Y(s[2]);
          if (s[0] === "slc") drawDiamond(g, x, y, i === 0 ? 7 : 5.5, SLC_COLOUR, true);
          else {
            g.beginPath();
            g.arc(x, y, i === 0 ? 6 : 4, 0, 2 * Math.PI);
            g.fillStyle = i === 0 ? TOUR_COLOUR : "#fff";
            g.fill();
            g.strokeStyle = TOUR_COLOUR;
            g.lineWidth = 1.8;
            g.stroke();
          }
        });
      }
      // landmarks of the final semantic map, by class; a faint ring at 2σ (horizontal) when it shows
      for (const lm of (state.stat && state.stat.landmarks) || []) {
        if (floorOf(lm.p[2]) !== fi) continue;
        const x = view.X(lm.p[0]), y = view.Y(lm.p[1]);
        const ring = 2 * lm.sigma * Math.SQRT1_2 * view.scale;
        g.strokeStyle = classColour(lm.class);
        if (ring > 7) {
          g.globalAlpha = 0.3;
          g.lineWidth = 1;
          g.beginPath(); g.arc(x, y, ring, 0, 2 * Math.PI); g.stroke();
          g.globalAlpha = 1;
        }
        g.beginPath();
        g.arc(x, y, 5, 0, 2 * Math.PI);
        g.fillStyle = classColour(lm.class);
        g.fill();
        g.strokeStyle = "#fff";
        g.lineWidth = 1.2;
        g.stroke();
      }
      // loop-closure attempts so far, where the robot was
      for (const e of state.events) {
        if (e.t > t) break;
        if (e.event !== "loop_closure") continue;
        const p = T.poseAt(state.traj.ground_truth || [], e.t, state.trajTimes.ground_truth);
        if (!p || floorOf(p[2]) !== fi) continue;
        const x = view.X(p[0]), y = view.Y(p[1]);
        if (e.accepted) {
          g.beginPath(); g.arc(x, y, 7, 0, 2 * Math.PI);
          g.strokeStyle = "#1f9e5a"; g.lineWidth = 2.5; g.stroke();
        } else drawCross(g, x, y, 6, "#d23b3b");
      }
      // a crash, where it happened
      for (const e of state.events) {
        if (e.t > t) break;
        if (e.event !== "sim_crash" && e.event !== "crash") continue;
        const p = e.position || T.poseAt(state.traj.ground_truth || [], e.t, state.trajTimes.ground_truth);
        if (!p || floorOf(p[2]) !== fi) continue;
        drawCross(g, view.X(p[0]), view.Y(p[1]), 11, "#b00020");
        break; // one mark: sim_crash and crash name the same collision
      }
      // estimates (hollow) and the true robot (filled)
      for (const name in estimates) {
        const p = estimates[name];
        if (p && floorOf(p[2]) === fi) drawRobot(g, view, p, null, TRAJ[name].colour, 9);
      }
      if (robot && floorOf(robot[2]) === fi) {
        g.beginPath(); // a halo, so the robot stands out on dark walls
        g.arc(view.X(robot[0]), view.Y(robot[1]), 15, 0, 2 * Math.PI);
        g.fillStyle = "rgba(255,214,0,0.45)";
        g.fill();
        drawRobot(g, view, robot, "#111", "#fff", 13);
      }
    });
  }

  // -- events --------------------------------------------------------------------------------------

  function summary(e) {
    switch (e.event) {
      case "replan": {
        const tour = e.tour || [];
        const slc = tour.filter((s) => s[0] === "slc").length;
        return tour.length + " stops" + (slc ? " (" + slc + " SLC)" : "") + ", next " + (tour[0] ? tour[0][0] : "—") +
          (e.viewpoints !== undefined ? " · " + e.viewpoints + " viewpoints" : "");
      }
      case "loop_closure":
      case "slam_loop_closure":
        return (e.accepted ? "accepted" : "rejected") + ": " + (e.reason || "") + (e.matched !== undefined ? " · matched " + e.matched : "");
      case "goal_done":
      case "unreachable":
        return (e.behaviour ? e.behaviour + ": " : "") + (e.why || "") + (e.goal ? " @ (" + e.goal.map((v) => fmt(v, 1)).join(", ") + ")" : "");
      case "planner_tour":
        return Object.entries(e).filter(([k]) => k !== "t" && k !== "event").map(([k, v]) => k + "=" + short(v, 30)).join(" ");
      default:
        return Object.entries(e)
          .filter(([k]) => k !== "t" && k !== "event" && k !== "traceback")
          .map(([k, v]) => k + "=" + short(v, 60))
          .join(" ");
    }
  }

  function addEventRows(events) {
    const list = $("events");
    const frag = document.createDocumentFragment();
    for (const e of events) {
      const row = document.createElement("div");
      const kind = EVENT_KIND[e.event] || "run";
      row.className = "ev k-" + kind + (e.accepted === true ? " accepted" : "");
      row.dataset.t = String(e.t);
      row.dataset.kind = kind;
      row.innerHTML = '<span class="et">' + esc(fmt(e.t, 1)) + '</span><span class="en">' + esc(e.event) +
        '</span><span class="es">' + esc(summary(e)) + "</span>";
      row.title = JSON.stringify(e, null, 1).slice(0, 2000);
      row.addEventListener("click", () => { stop(); setTime(e.t); });
      frag.appendChild(row);
      state.eventRows.push(row);
    }
    list.appendChild(frag);
    applyFilter();
  }

  function applyFilter() {
    const f = $("filter").value;
    for (const row of state.eventRows) row.hidden = !(f === "all" || row.dataset.kind === f);
  }

  let currentEvent = null;
  function renderEvents(scroll) {
    if (state.eventTimes.length !== state.events.length) state.eventTimes = state.events.map((e) => e.t);
    const i = T.upperBound(state.eventTimes, state.t) - 1;
    const row = i >= 0 ? state.eventRows[i] : null;
    if (row === currentEvent) return;
    if (currentEvent) currentEvent.classList.remove("current");
    currentEvent = row;
    if (row) {
      row.classList.add("current");
      if (scroll && !row.hidden) row.scrollIntoView({ block: "nearest" });
    }
  }

  // -- time ----------------------------------------------------------------------------------------

  function setTime(t, fromSlider) {
    state.t = Math.max(0, Math.min(t, state.end));
    if (!fromSlider) $("slider").value = String(state.t);
    render(true);
  }

  function render(scroll) {
    const s = state.timeline.stateAt(state.t);
    $("t-now").textContent = fmt(state.t, 1);
    renderTree(s);
    const robot = T.poseAt(state.traj.ground_truth || [], state.t, state.trajTimes.ground_truth);
    const readout = $("robot");
    if (robot) {
      readout.textContent = "robot x " + fmt(robot[0]) + "  y " + fmt(robot[1]) + "  z " + fmt(robot[2]) +
        "  yaw " + Math.round((robot[3] * 180) / Math.PI) + "°  · floor " + floorOf(robot[2]);
    } else readout.textContent = "robot: no pose yet";
    readout.dataset.x = robot ? robot[0].toFixed(3) : "";
    readout.dataset.y = robot ? robot[1].toFixed(3) : "";
    renderMaps(robot);
    renderEvents(scroll);
  }

  let lastFrame = null;
  function frame(now) {
    if (!state.playing) return;
    if (lastFrame !== null) {
      const t = state.t + ((now - lastFrame) / 1000) * state.speed;
      if (t >= state.end && state.finished) { setTime(state.end); stop(); return; }
      setTime(Math.min(t, state.end));
    }
    lastFrame = now;
    requestAnimationFrame(frame);
  }

  function play() {
    if (state.t >= state.end && state.finished) setTime(0);
    state.playing = true;
    lastFrame = null;
    $("play").textContent = "❚❚";
    $("play").title = "pause (space)";
    requestAnimationFrame(frame);
  }

  function stop() {
    state.playing = false;
    $("play").textContent = "▶";
    $("play").title = "play (space)";
  }

  // -- live ----------------------------------------------------------------------------------------

  function merge(delta) {
    let rebuildMaps = false;
    if (delta.structure) {
      state.timeline = new T.TreeTimeline(delta.structure, state.timeline.records);
      buildTree();
    }
    if (delta.tree.length) state.timeline.add(delta.tree);
    if (delta.events.length) {
      state.events.push(...delta.events);
      addEventRows(delta.events);
    }
    for (const name in delta.traj) {
      if (delta.reset.includes(name)) state.traj[name] = [];
      state.traj[name] = (state.traj[name] || []).concat(delta.traj[name]);
    }
    if (delta.static) {
      state.stat = delta.static;
      rebuildMaps = true;
    }
    if (delta.finished && !state.finished) {
      state.finished = true;
      rebuildMaps = true;
    }
    const b = state.bounds;
    refreshTimes();
    computeBounds();
    const nb = state.bounds;
    if (rebuildMaps || !b || nb.x0 < b.x0 || nb.y0 < b.y0 || nb.x1 > b.x1 || nb.y1 > b.y1) buildMaps();
    else state.bounds = b;
    renderHeader();
  }

  async function poll() {
    try {
      const response = await fetch(live.endpoint + "?cursor=" + encodeURIComponent(JSON.stringify(live.cursor)), { cache: "no-store" });
      if (!response.ok) throw new Error(response.status + " " + response.statusText);
      const delta = await response.json();
      live.cursor = delta.cursor;
      merge(delta);
      $("live").textContent = state.finished ? "run finished" : "live · updated " + new Date().toLocaleTimeString();
      $("live").className = "badge " + (state.finished ? "ok" : "live");
      if (state.follow) setTime(state.end);
      else render(false);
    } catch (err) {
      $("live").textContent = "live: " + err.message;
      $("live").className = "badge bad";
    }
    if (!state.finished) setTimeout(poll, live.interval || 1000);
  }

  // -- wiring --------------------------------------------------------------------------------------

  function init() {
    refreshTimes();
    renderHeader();
    buildTree();
    buildMaps();
    addEventRows(state.events);
    const slider = $("slider");
    slider.addEventListener("input", () => { stop(); state.follow = false; syncFollow(); setTime(parseFloat(slider.value), true); });
    $("play").addEventListener("click", () => (state.playing ? stop() : play()));
    $("speed").addEventListener("change", (e) => { state.speed = parseFloat(e.target.value); });
    $("prev").addEventListener("click", () => { stop(); const t = state.timeline.previousChange(state.t); if (t !== null) setTime(t); });
    $("next").addEventListener("click", () => { stop(); const t = state.timeline.nextChange(state.t); if (t !== null) setTime(t); });
    $("filter").addEventListener("change", applyFilter);
    $("follow").addEventListener("change", (e) => { state.follow = e.target.checked; if (state.follow) setTime(state.end); });
    document.addEventListener("keydown", (e) => {
      const tag = e.target.tagName;
      if (tag === "SELECT" || (tag === "INPUT" && e.target.type !== "range")) return;
      if (e.key === " ") {
        e.preventDefault();
        state.playing ? stop() : play();
      } else if (e.key === "ArrowRight" || e.key === "ArrowLeft") {
        e.preventDefault(); // on the slider too: arrows step through the tree's changes, shift by 10 s
        const forward = e.key === "ArrowRight";
        $(e.shiftKey ? (forward ? "fwd" : "back") : forward ? "next" : "prev").click();
      }
    });
    $("back").addEventListener("click", () => { stop(); setTime(state.t - 10); });
    $("fwd").addEventListener("click", () => { stop(); setTime(state.t + 10); });
    let resizeTimer = null;
    window.addEventListener("resize", () => {
      clearTimeout(resizeTimer);
      resizeTimer = setTimeout(() => { buildMaps(); render(false); }, 150);
    });
    syncFollow();
    if (live) {
      $("live").hidden = false;
      $("follow-box").hidden = false;
    }
    const start = parseFloat(new URLSearchParams(location.search).get("t"));
    setTime(isFinite(start) ? start : live ? state.end : 0);
    if (live && !state.finished) setTimeout(poll, 200);
  }

  function syncFollow() {
    $("follow").checked = state.follow;
  }

  window.amslamViewer = {
    setTime: (t) => { stop(); state.follow = false; syncFollow(); setTime(t); },
    time: () => state.t,
    end: () => state.end,
    statuses: () => {
      const out = {};
      for (const id in state.rows) out[state.rows[id].dataset.name] = state.rows[id].dataset.status;
      return out;
    },
    robot: () => T.poseAt(state.traj.ground_truth || [], state.t, state.trajTimes.ground_truth),
    finished: () => state.finished,
    /** Device pixel of world point (x, y) on floor i's canvas (for tests and tools reading pixels). */
    toCanvas: (i, x, y) => {
      const v = state.floorCanvases[i];
      return [Math.round(v.X(x) * v.dpr), Math.round(v.Y(y) * v.dpr)];
    },
    records: () => state.timeline.records.length,
  };

  init();
})();
