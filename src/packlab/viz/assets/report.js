// packlab bench report: builds every table, plot and 3D replay from the data embedded once in
// the page (script#packlab-data, layout in packlab/viz/report_data.py). No network access.
(function () {
  "use strict";
  var state = (window.packlabReport = { ready: false, errors: [], panes: {} });
  window.addEventListener("error", function (e) {
    state.errors.push(String(e.message || e));
  });

  var D = JSON.parse(document.getElementById("packlab-data").textContent);
  var PAGE = 100; // browser rows shown before "Show all"

  // -- small helpers -----------------------------------------------------------------------
  function el(tag, attrs, children) {
    var e = document.createElement(tag);
    Object.keys(attrs || {}).forEach(function (k) {
      if (k === "text") e.textContent = attrs[k];
      else if (k === "cls") e.className = attrs[k];
      else if (k.slice(0, 2) === "on") e.addEventListener(k.slice(2), attrs[k]);
      else e.setAttribute(k, attrs[k]);
    });
    (children || []).forEach(function (c) {
      e.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    });
    return e;
  }
  function fmt(x, digits) {
    return x === null || x === undefined ? "-" : Number(x).toFixed(digits === undefined ? 3 : digits);
  }
  function option(value, text) {
    return el("option", { value: String(value), text: text });
  }
  function swatch(colour) {
    var s = el("span", { cls: "swatch" });
    s.style.background = colour;
    return s;
  }
  function episodeKey(m, c, s) {
    return m + "|" + c + "|" + s;
  }
  var byKey = {};
  D.episodes.forEach(function (e) {
    byKey[episodeKey(e.m, e.c, e.s)] = e;
  });
  function overallOf(e) {
    return e.metrics ? e.metrics.overall : -1; // failed episodes sort first (worst)
  }

  // Sort a table's body by a column when its header (th[data-col]) is clicked; each cell holds
  // its sort value in data-v (numbers compare as numbers).
  function makeSortable(table) {
    table.querySelectorAll("th[data-col]").forEach(function (th) {
      th.addEventListener("click", function () {
        var col = Number(th.getAttribute("data-col"));
        var asc = !th.classList.contains("sorted-asc");
        table.querySelectorAll("th").forEach(function (h) {
          h.classList.remove("sorted-asc", "sorted-desc");
        });
        th.classList.add(asc ? "sorted-asc" : "sorted-desc");
        var body = table.tBodies[0];
        var rows = Array.prototype.slice.call(body.rows);
        rows.sort(function (a, b) {
          var x = a.cells[col].getAttribute("data-v"), y = b.cells[col].getAttribute("data-v");
          var nx = parseFloat(x), ny = parseFloat(y);
          var r = !isNaN(nx) && !isNaN(ny) ? nx - ny : String(x).localeCompare(String(y));
          return asc ? r : -r;
        });
        rows.forEach(function (r) {
          body.appendChild(r);
        });
      });
    });
  }
  function td(text, sortValue, cls) {
    var c = el("td", { text: text, "data-v": String(sortValue === undefined ? text : sortValue) });
    if (cls) c.className = cls;
    return c;
  }

  // -- header ------------------------------------------------------------------------------
  // One calm line on top (the best method and its Average Overall with its interval); the
  // notes list only what needs the reader's attention (failures, replays missing).
  function renderHeader() {
    document.getElementById("title").textContent = D.title;
    document.getElementById("subtitle").textContent = D.subtitle;
    var meta = document.querySelector('meta[name="packlab-generated"]');
    document.getElementById("generated").textContent = "Generated " + meta.content;
    var line = document.getElementById("headline");
    line.textContent = D.headline || "";
    line.style.display = D.headline ? "" : "none";
    var notes = document.getElementById("notes");
    D.notes.forEach(function (n) {
      notes.appendChild(el("li", { text: n }));
    });
    notes.style.display = D.notes.length ? "" : "none";
  }

  // -- results and details tables ----------------------------------------------------------
  // A cell is [mean, std] (summaries before intervals) or [mean, std, low, high]: the 95 %
  // bootstrap interval over cases when both bounds are there, else the old "± sd" form.
  function hasInterval(c) {
    return !!c && c.length >= 4 && c[2] !== null && c[2] !== undefined &&
      c[3] !== null && c[3] !== undefined;
  }
  function spread(c) {
    if (hasInterval(c)) return el("span", { cls: "sd ci", text: " [" + fmt(c[2]) + ", " + fmt(c[3]) + "]" });
    return el("span", { cls: "sd", text: " ± " + fmt(c[1] || 0) });
  }
  function resultsCaption() {
    var caption = document.querySelector("#results > p.muted");
    var any = D.methods.some(function (m) { return m.cells.some(hasInterval); });
    if (!caption || !any) return; // old summaries keep the page's own "± sd" caption
    caption.textContent = "Mean over seeds; the headline column (" + headlineTitle() + " Overall) " +
      "with its 95 % bootstrap interval over cases [low, high]: hover any cell for its own, or " +
      "tick \"intervals in every cell\". Rows best first (the oracle, a ceiling, last); bold: " +
      "the best method of each column (the oracle aside). Click a column header to sort.";
  }

  // The results table's columns: Method, then the headline group (Average, or the only level)
  // and the levels, Overall first in each, so the headline column is the second one and on
  // screen without scrolling. col.cell indexes a method's cells (groups x metrics, data order).
  function resultsLayout() {
    var groups = D.groups.map(function (_, gi) { return gi; });
    if (groups.length > 1) groups.unshift(groups.pop());
    var metrics = D.metrics.map(function (_, mi) { return mi; });
    var overall = D.metrics.findIndex(function (m) { return m[0] === "overall"; });
    if (overall > 0) metrics.unshift(metrics.splice(overall, 1)[0]);
    var cols = [];
    groups.forEach(function (gi, k) {
      metrics.forEach(function (mi, j) {
        cols.push({ group: gi, metric: mi, cell: gi * D.metrics.length + mi, first: j === 0,
          headline: k === 0 && j === 0 });
      });
    });
    return { groups: groups, metrics: metrics, cols: cols };
  }
  function headlineTitle() {
    var g = D.groups[resultsLayout().groups[0]];
    return g ? g[1] : "";
  }
  // Rows best first by the headline column; the oracle (a ceiling) and unscored rows last.
  function rankedMethods(cell) {
    function key(m) {
      var c = m.cells[cell], mean = c ? c[0] : null;
      return [m.policy === "oracle" ? 1 : 0, mean === null ? 1 : 0, mean === null ? 0 : -mean];
    }
    return D.methods.map(function (m, i) { return [key(m), i, m]; }).sort(function (a, b) {
      for (var k = 0; k < 3; k++) if (a[0][k] !== b[0][k]) return a[0][k] - b[0][k];
      return a[1] - b[1];
    }).map(function (x) { return x[2]; });
  }
  function renderResults() {
    resultsCaption();
    var layout = resultsLayout();
    var table = document.getElementById("results-table");
    // Two header rows: each group's cell spans exactly its metric columns (colspan).
    var top = el("tr", {}, [el("th", { text: "Method", rowspan: "2", "data-col": "0" })]);
    var sub = el("tr");
    layout.groups.forEach(function (gi) {
      top.appendChild(el("th", { text: D.groups[gi][1], colspan: String(layout.metrics.length),
        cls: "group group-start", "data-group": D.groups[gi][0] }));
    });
    layout.cols.forEach(function (col, i) {
      var th = el("th", { text: D.metrics[col.metric][1], "data-col": String(i + 1),
        "data-group": D.groups[col.group][0], cls: col.first ? "group-start" : "" });
      if (col.headline) th.id = "results-headline";
      sub.appendChild(th);
    });
    table.appendChild(el("thead", {}, [top, sub]));
    var best = D.methods[0] ? D.methods[0].cells.map(function () { return -Infinity; }) : [];
    D.methods.forEach(function (m) {
      if (m.policy === "oracle") return; // the ceiling, not a competitor
      m.cells.forEach(function (c, i) {
        if (c && c[0] !== null && c[0] > best[i]) best[i] = c[0];
      });
    });
    var body = el("tbody");
    var first = layout.cols.length ? layout.cols[0].cell : 0;
    rankedMethods(first).forEach(function (m) {
      var name = el("td", { "data-v": m.name }, [swatch(m.colour), m.name + (m.counts.errors ? " *" : "")]);
      var row = el("tr", {}, [name]);
      layout.cols.forEach(function (col) {
        var c = m.cells[col.cell], mean = c ? c[0] : null;
        var cls = [col.first ? "group-start" : "", col.headline ? "headline" : "",
          mean !== null && mean === best[col.cell] && m.policy !== "oracle" ? "best" : ""];
        var cell = td(mean === null ? "-" : fmt(mean), mean === null ? -1 : mean,
          cls.filter(Boolean).join(" "));
        if (mean !== null) {
          var extra = spread(c);
          cell.appendChild(extra);
          cell.title = D.groups[col.group][1] + " " + D.metrics[col.metric][1] + ": " + fmt(mean) + extra.textContent;
        }
        row.appendChild(cell);
      });
      body.appendChild(row);
    });
    table.appendChild(body);
    makeSortable(table);
    document.getElementById("t-intervals").addEventListener("change", function (e) {
      table.classList.toggle("all-intervals", e.target.checked);
    });
    renderDifferences();
  }
  // A comparison's paired differences to its first row (one line each), under the table.
  function renderDifferences() {
    var box = document.getElementById("differences"), lines = D.differences || [];
    box.style.display = lines.length ? "" : "none";
    if (!lines.length) return;
    box.appendChild(el("h3", { text: "Paired differences (" + headlineTitle() + " Overall)" }));
    box.appendChild(el("ul", { cls: "muted" }, lines.map(function (t) { return el("li", { text: t }); })));
  }

  function renderDetails() {
    var cols = [
      ["episodes", "episodes", 0], ["errors", "errors", 0], ["invalid_steps", "invalid actions", 0],
      ["set_aside", "set aside", 0], ["unsettled_steps", "unsettled steps", 0],
      ["not_at_rest", "not at rest", 0], ["decision_ms", "ms / decision", 2],
      ["step_ms", "ms / env step", 2], ["episode_s", "s / episode", 3],
    ].concat(D.details_extra || []); // e.g. the answer formats of rows that read a model's text
    var table = document.getElementById("details-table");
    var head = el("tr", {}, [el("th", { text: "Method", "data-col": "0" })]);
    cols.forEach(function (c, i) {
      head.appendChild(el("th", { text: c[1], "data-col": String(i + 1) }));
    });
    table.appendChild(el("thead", {}, [head]));
    var body = el("tbody");
    var layout = resultsLayout(); // the same row order as the results table above it
    rankedMethods(layout.cols.length ? layout.cols[0].cell : 0).forEach(function (m) {
      var row = el("tr", {}, [td(m.name)]);
      cols.forEach(function (c) {
        var v = m.counts[c[0]];
        row.appendChild(td(v === null || v === undefined ? "-" : fmt(v, c[2]), v === null ? -1 : v));
      });
      body.appendChild(row);
    });
    table.appendChild(body);
    makeSortable(table);
  }

  // -- per-level box plots of per-case Overall --------------------------------------------
  function caseMeans(m) {
    var sums = {};
    D.episodes.forEach(function (e) {
      if (e.m !== m || !e.metrics) return;
      var s = sums[e.c] || (sums[e.c] = [0, 0]);
      s[0] += e.metrics.overall;
      s[1] += 1;
    });
    return sums;
  }
  function renderBoxes() {
    var traces = [], levels = D.levels.length ? D.levels : [""];
    var layout = {
      margin: { l: 50, r: 10, t: 50, b: 110 }, showlegend: false, boxmode: "overlay",
      yaxis: { title: { text: "Overall" }, range: [-0.03, 1.05], zeroline: false },
      annotations: [],
    };
    var width = 1 / levels.length;
    levels.forEach(function (level, k) {
      var ax = k === 0 ? "" : String(k + 1);
      layout["xaxis" + ax] = { domain: [k * width + 0.01, (k + 1) * width - 0.01], tickangle: -30, automargin: true };
      layout.annotations.push({
        text: "<b>" + (level ? level.charAt(0).toUpperCase() + level.slice(1) : "all") + "</b>",
        x: (k + 0.5) * width, y: 1.0, yanchor: "bottom", xref: "paper", yref: "paper", showarrow: false,
      });
      D.methods.forEach(function (m, mi) {
        var sums = caseMeans(mi), ys = [], cases = [];
        Object.keys(sums).forEach(function (c) {
          if (level && D.cases[c].level !== level) return;
          ys.push(sums[c][0] / sums[c][1]);
          cases.push([Number(c), mi, D.cases[c].id]);
        });
        traces.push({
          type: "box", y: ys, x: ys.map(function () { return m.name; }), name: m.name,
          xaxis: "x" + ax, yaxis: "y", marker: { color: m.colour, size: 4 },
          line: { width: 1.2 }, boxpoints: "all", jitter: 0.4, pointpos: 0,
          customdata: cases, hovertemplate: "%{customdata[2]}<br>Overall %{y:.3f}<extra>" + m.name + "</extra>",
        });
      });
    });
    var div = document.getElementById("box-plot");
    return Plotly.newPlot(div, traces, layout, { responsive: true, displaylogo: false }).then(function () {
      div.on("plotly_click", function (ev) {
        var cd = ev.points && ev.points[0] && ev.points[0].customdata;
        if (cd) openEpisode(cd[0], null, cd[1]);
      });
    });
  }

  // -- case browser ------------------------------------------------------------------------
  var browserAll = false;
  function fillSelect(sel, items, withAll) {
    if (withAll) sel.appendChild(option("", "all"));
    items.forEach(function (it) {
      sel.appendChild(option(it[0], it[1]));
    });
  }
  function renderBrowserControls() {
    fillSelect(document.getElementById("f-level"), D.levels.map(function (l) { return [l, l]; }), true);
    fillSelect(document.getElementById("f-method"), D.methods.map(function (m, i) { return [i, m.name]; }), true);
    fillSelect(document.getElementById("f-seed"), D.seeds.map(function (s) { return [s, String(s)]; }), true);
    ["f-level", "f-method", "f-seed", "f-min", "f-max", "f-case"].forEach(function (id) {
      ["input", "change"].forEach(function (kind) {
        document.getElementById(id).addEventListener(kind, function () {
          browserAll = false;
          renderBrowser();
        });
      });
    });
    document.getElementById("f-more").addEventListener("click", function () {
      browserAll = true;
      renderBrowser();
    });
  }
  function browserRows() {
    var level = document.getElementById("f-level").value;
    var method = document.getElementById("f-method").value;
    var seed = document.getElementById("f-seed").value;
    var lo = parseFloat(document.getElementById("f-min").value);
    var hi = parseFloat(document.getElementById("f-max").value);
    var text = document.getElementById("f-case").value.trim();
    var rows = D.episodes.filter(function (e) {
      var c = D.cases[e.c], o = overallOf(e);
      if (level && c.level !== level) return false;
      if (method !== "" && e.m !== Number(method)) return false;
      if (seed !== "" && e.s !== Number(seed)) return false;
      if (text && c.id.indexOf(text) < 0) return false;
      if (e.metrics && ((!isNaN(lo) && o < lo) || (!isNaN(hi) && o > hi))) return false;
      return true;
    });
    rows.sort(function (a, b) {
      return overallOf(a) - overallOf(b) || a.c - b.c || a.m - b.m || a.s - b.s;
    });
    return rows;
  }
  function renderBrowser() {
    var table = document.getElementById("browser-table");
    table.innerHTML = "";
    var names = ["#", "case", "level", "method", "seed", "Overall", "SR", "Compact.", "inside", "set aside", "invalid actions"];
    var head = el("tr");
    names.forEach(function (n, i) {
      head.appendChild(el("th", { text: n, "data-col": String(i), cls: i > 0 && i < 4 ? "text" : "" }));
    });
    table.appendChild(el("thead", {}, [head]));
    var rows = browserRows(), body = el("tbody");
    var shown = browserAll ? rows : rows.slice(0, PAGE);
    shown.forEach(function (e, i) {
      var c = D.cases[e.c], m = D.methods[e.m], x = e.metrics;
      var tr = el("tr", { onclick: function () { openEpisode(e.c, e.s, e.m); } }, [
        td(String(i + 1), i), td(c.id, c.id, "text"), td(c.level, c.level, "text"),
        td(m.name, m.name, "text"), td(e.reused_from === undefined ? String(e.s) : e.s + " (copy of " + e.reused_from + ")", e.s),
      ]);
      if (!x) {
        tr.className = "error";
        var msg = el("td", { text: e.error, colspan: "6", cls: "text", "data-v": "-1" });
        tr.appendChild(msg);
      } else {
        tr.appendChild(td(fmt(x.overall), x.overall));
        tr.appendChild(td(fmt(x.success_ratio), x.success_ratio));
        tr.appendChild(td(fmt(x.compactness), x.compactness));
        tr.appendChild(td(x.inside + "/" + x.objects, x.inside / Math.max(1, x.objects)));
        tr.appendChild(td(String(x.set_aside), x.set_aside));
        tr.appendChild(td(String(x.invalid), x.invalid));
      }
      body.appendChild(tr);
    });
    table.appendChild(body);
    makeSortable(table);
    document.getElementById("f-count").textContent =
      rows.length + " episodes, worst first" + (shown.length < rows.length ? "; showing " + shown.length : "");
    document.getElementById("f-more").style.display = shown.length < rows.length ? "" : "none";
  }

  // -- geometry ----------------------------------------------------------------------------
  // Corner k of a box has bits (x, y, z) = (k >> 2 & 1, k >> 1 & 1, k & 1).
  var TRIS = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
              [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]];
  var EDGES = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];
  function rotate(q, v) {
    var n = Math.hypot(q[0], q[1], q[2], q[3]) || 1;
    var w = q[0] / n, x = q[1] / n, y = q[2] / n, z = q[3] / n;
    return [
      (1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y - w * z) * v[1] + 2 * (x * z + w * y) * v[2],
      2 * (x * y + w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z - w * x) * v[2],
      2 * (x * z - w * y) * v[0] + 2 * (y * z + w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2],
    ];
  }
  function corners(size, pose) {
    var out = [];
    for (var k = 0; k < 8; k++) {
      var v = [((k >> 2) & 1) - 0.5, ((k >> 1) & 1) - 0.5, (k & 1) - 0.5];
      var r = rotate(pose.slice(3, 7), [v[0] * size[0], v[1] * size[1], v[2] * size[2]]);
      out.push([r[0] + pose[0], r[1] + pose[1], r[2] + pose[2]]);
    }
    return out;
  }
  // Boxes [{size, pose, colour, label}] as one mesh3d trace and one edge-lines trace.
  function boxTraces(boxes, opacity, edgeColour, edgeWidth) {
    var mesh = { type: "mesh3d", x: [], y: [], z: [], i: [], j: [], k: [], facecolor: [], text: [],
      hoverinfo: "text", flatshading: true, opacity: opacity,
      lighting: { ambient: 0.75, diffuse: 0.5, specular: 0.05 }, showscale: false };
    var lines = { type: "scatter3d", mode: "lines", x: [], y: [], z: [], hoverinfo: "skip",
      line: { color: edgeColour, width: edgeWidth }, showlegend: false };
    boxes.forEach(function (b) {
      var base = mesh.x.length, cs = corners(b.size, b.pose);
      cs.forEach(function (c) {
        mesh.x.push(c[0]); mesh.y.push(c[1]); mesh.z.push(c[2]); mesh.text.push(b.label);
      });
      TRIS.forEach(function (t) {
        mesh.i.push(base + t[0]); mesh.j.push(base + t[1]); mesh.k.push(base + t[2]);
        mesh.facecolor.push(b.colour);
      });
      EDGES.forEach(function (e) {
        [cs[e[0]], cs[e[1]], [null, null, null]].forEach(function (p) {
          lines.x.push(p[0]); lines.y.push(p[1]); lines.z.push(p[2]);
        });
      });
    });
    if (!boxes.length) { mesh.visible = false; lines.visible = false; }
    return [mesh, lines];
  }
  function containerTrace(size) {
    var t = { type: "scatter3d", mode: "lines", x: [], y: [], z: [], hoverinfo: "skip",
      line: { color: "#666", width: 3 }, showlegend: false };
    var cs = corners(size, [size[0] / 2, size[1] / 2, size[2] / 2, 1, 0, 0, 0]);
    EDGES.forEach(function (e) {
      [cs[e[0]], cs[e[1]], [null, null, null]].forEach(function (p) {
        t.x.push(p[0]); t.y.push(p[1]); t.z.push(p[2]);
      });
    });
    return t;
  }

  // -- replay panes ------------------------------------------------------------------------
  var replay = { c: 0, s: D.seeds[0] };
  function typeColour(t) {
    return D.type_colours[t % D.type_colours.length];
  }
  function boxLabel(c, i) {
    var b = c.boxes[i], id = c.ids[i] === String(i) ? "" : " (" + c.ids[i] + ")";
    return "#" + i + id + " " + b[0] + "×" + b[1] + "×" + b[2] + " mm";
  }
  // Poses after step k (1-based count of steps done) and the objects set aside by then.
  function stateAfter(ep, k) {
    var poses = {}, aside = [];
    for (var t = 0; t < k; t++) {
      var st = ep.steps[t];
      if (st[2] !== 0) aside.push(st[0]);
      st[4].forEach(function (p) { poses[p[0]] = p.slice(1); });
    }
    return { poses: poses, aside: aside };
  }
  // Boxes laid out on the floor in rows of at most `width` along x, from (x0, y0) towards -y
  // (dir -1: the buffer, in front of the container) or +y (dir 1: set-aside boxes, beside it).
  function rowLayout(c, indices, x0, y0, width, dir, gap) {
    var out = [], x = x0, y = y0, depth = 0, right = x0;
    indices.forEach(function (i) {
      if (i < 0) return;
      var b = c.boxes[i];
      if (x > x0 && x + b[0] > x0 + width) { x = x0; y += dir * (depth + gap); depth = 0; }
      out.push({ i: i, pose: [x + b[0] / 2, y + dir * b[1] / 2, b[2] / 2, 1, 0, 0, 0] });
      right = Math.max(right, x + b[0]);
      x += b[0] + gap;
      depth = Math.max(depth, b[1]);
    });
    return { boxes: out, extent: y + dir * depth, right: right };
  }
  function placements(c, gap) {
    var X = c.container[0], Y = c.container[1], maxL = 0;
    c.boxes.forEach(function (b) { maxL = Math.max(maxL, b[0]); });
    var asideWidth = Math.max(maxL, 0.5 * X);
    return {
      // Rows twice as long as the container is wide keep a 10-object buffer to two or three rows.
      buffer: function (shown) { return rowLayout(c, shown, 0, -gap, Math.max(2 * Math.max(X, Y), maxL), -1, gap); },
      aside: function (list) { return rowLayout(c, list, X + 2 * gap, 0, asideWidth, 1, gap); },
      asideWidth: asideWidth,
    };
  }
  function layoutFor(c, ep, uirev, showBuffer) {
    var X = c.container[0], Y = c.container[1], Z = c.container[2];
    var gap = Math.max(20, 0.04 * Math.max(X, Y));
    var place = placements(c, gap), maxDim = 0, top = Z, front = 0, aside = [], right = X, bufRight = X;
    c.boxes.forEach(function (b) { maxDim = Math.max(maxDim, b[0], b[1], b[2]); });
    ep.steps.forEach(function (st) {
      if (showBuffer) {
        var row = place.buffer(st[3]);
        front = Math.min(front, row.extent);
        bufRight = Math.max(bufRight, row.right);
      }
      if (st[2] !== 0) aside.push(st[0]);
      st[4].forEach(function (p) { top = Math.max(top, p[3] + maxDim / 2); });
    });
    var back = Y;
    if (aside.length) {
      back = Math.max(Y, place.aside(aside).extent);
      right = X + 2 * gap + place.asideWidth;
    }
    right = Math.max(right, bufRight);
    var xr = [-gap, right + gap], yr = [front - gap, back + gap], zr = [0, top + gap];
    var span = Math.max(xr[1] - xr[0], yr[1] - yr[0], zr[1] - zr[0]);
    return {
      margin: { l: 0, r: 0, t: 0, b: 0 }, showlegend: false, uirevision: uirev,
      scene: {
        uirevision: uirev, aspectmode: "manual",
        aspectratio: { x: (xr[1] - xr[0]) / span, y: (yr[1] - yr[0]) / span, z: (zr[1] - zr[0]) / span },
        xaxis: { range: xr, title: { text: "x (mm)" } }, yaxis: { range: yr, title: { text: "y (mm)" } },
        zaxis: { range: zr, title: { text: "z (mm)" } },
        camera: { eye: { x: 1.15, y: -1.7, z: 1.15 } },
      },
      gap: gap,
    };
  }
  // A box counts as packed when its centre is inside the container (1 mm tolerance; DESIGN 5).
  function inside(size, p) {
    return p[0] >= -1 && p[0] <= size[0] + 1 && p[1] >= -1 && p[1] <= size[1] + 1 && p[2] >= -1 && p[2] <= size[2] + 1;
  }
  function sceneTraces(c, ep, k, gap, showBuffer) {
    var st = stateAfter(ep, k), step = ep.steps[k - 1], place = placements(c, gap);
    var packed = [], outside = [], last = [], buf = [], chosen = [], aside = [];
    Object.keys(st.poses).forEach(function (i) {
      var b = c.boxes[i], p = st.poses[i], box = { size: b, pose: p, colour: typeColour(b[3]), label: boxLabel(c, Number(i)) };
      packed.push(box);
      if (!inside(c.container, p)) outside.push(box);
      if (step[2] === 0 && Number(i) === step[0]) last.push(box);
    });
    place.buffer(showBuffer ? step[3] : []).boxes.forEach(function (p) {
      var b = c.boxes[p.i];
      var box = { size: b, pose: p.pose, colour: typeColour(b[3]), label: "buffer: " + boxLabel(c, p.i) };
      (p.i === step[0] ? chosen : buf).push(box);
    });
    place.aside(st.aside).boxes.forEach(function (p) {
      aside.push({ size: c.boxes[p.i], pose: p.pose, colour: "#d9534f", label: "set aside: " + boxLabel(c, p.i) });
    });
    var labels = { type: "scatter3d", mode: "text", x: [], y: [], z: [], text: [], hoverinfo: "skip",
      textfont: { color: "#b00020", size: 12 }, showlegend: false };
    function label(text, boxes) {
      if (!boxes.length) return;
      var p = boxes[0].pose, b = boxes[0].size;
      labels.x.push(p[0] - b[0] / 2); labels.y.push(p[1]); labels.z.push(b[2] + gap); labels.text.push(text);
    }
    label("buffer", buf.concat(chosen).sort(function (u, v) { return u.pose[0] - v.pose[0]; }));
    label("set aside", aside);
    if (!labels.x.length) labels.visible = false;
    return [containerTrace(c.container)]
      .concat(boxTraces(packed, 1, "#333", 2))
      .concat(boxTraces(outside, 1, "#e00000", 6))
      .concat(boxTraces(last, 1, "#000", 7))
      .concat(boxTraces(buf, 0.45, "#555", 2))
      .concat(boxTraces(chosen, 0.6, "#b00020", 6))
      .concat(boxTraces(aside, 0.5, "#b00020", 2))
      .concat([labels]);
  }

  function Pane(id, methodIndex) {
    this.id = id;
    this.m = methodIndex;
    this.k = 1;
    var root = document.getElementById(id), self = this;
    this.select = el("select", { onchange: function () { self.m = Number(self.select.value); self.show(); } });
    D.methods.forEach(function (m, i) { self.select.appendChild(option(i, m.name)); });
    this.title = el("span", { cls: "muted" });
    this.showBuffer = el("input", { type: "checkbox", id: id + "-buffer3d",
      onchange: function () { if (self.ep) { self.view = self.layout(); self.draw(true); } } });
    this.scene = el("div", { cls: "scene", id: id + "-scene" });
    this.message = el("div", { cls: "message" });
    this.slider = el("input", { type: "range", min: "1", max: "1", value: "1", id: id + "-slider",
      oninput: function () { self.setStep(Number(self.slider.value), true); } });
    this.stepLabel = el("span", { id: id + "-step" });
    this.prev = el("button", { type: "button", text: "◀", onclick: function () { self.setStep(self.k - 1, true); } });
    this.next = el("button", { type: "button", text: "▶", onclick: function () { self.setStep(self.k + 1, true); } });
    this.strip = el("div", { cls: "strip" });
    this.status = el("div", { cls: "status", id: id + "-status" });
    this.note = el("div", { cls: "note" });
    this.buffer = el("ol", { start: "0" });
    this.metrics = el("dl");
    this.body = el("div", {}, [
      this.scene, el("div", { cls: "stepbar" }, [this.prev, this.slider, this.next, this.stepLabel]),
      this.strip, this.status, this.note,
      el("div", { cls: "legend muted", text: "Black outline: the box placed at this step; red outline: centre outside the container (not counted as packed); red boxes beside the container: set aside." }),
      el("div", { cls: "cols" }, [
        el("div", {}, [el("b", { text: "Buffer shown at this step" }), this.buffer]),
        el("div", {}, [el("b", { text: "Final metrics" }), this.metrics]),
      ]),
    ]);
    root.appendChild(el("div", { cls: "head" }, [el("label", {}, ["Method ", this.select]), this.title,
      el("label", {}, [this.showBuffer, "buffer in 3D"])]));
    root.appendChild(this.message);
    root.appendChild(this.body);
    this.select.value = String(methodIndex);
    state.panes[id] = this;
  }
  Pane.prototype.episode = function () {
    return byKey[episodeKey(this.m, replay.c, replay.s)];
  };
  Pane.prototype.show = function () {
    var c = D.cases[replay.c], ep = this.episode();
    this.select.value = String(this.m);
    var why = !ep ? "No episode of this method on this case and seed." :
      ep.error ? "This episode failed: " + ep.error :
      !c.boxes ? "No replay: the run directory's cases.jsonl does not hold this case." :
      !ep.steps.length ? "This episode has no steps." : "";
    this.message.textContent = why;
    this.message.style.display = why ? "" : "none";
    this.body.style.display = why ? "none" : "";
    this.title.textContent = c.id + " (" + c.level + "), seed " + replay.s +
      (ep && ep.reused_from !== undefined ? " (the episode of seed " + ep.reused_from + ": this policy's episodes do not depend on the run seed)" : "");
    if (why) { this.ep = null; return Promise.resolve(); }
    this.ep = ep;
    this.view = this.layout();
    this.slider.max = String(ep.steps.length);
    this.note.textContent = ep.poses === "recorded" ? "" : "Poses: " + D.pose_sources[ep.poses] + ".";
    this.renderStrip();
    this.renderMetrics();
    this.k = ep.steps.length; // a new episode opens on its final packing
    return this.draw(true);
  };
  Pane.prototype.layout = function () {
    var rev = this.id + "|" + replay.c + "|" + this.showBuffer.checked;
    return layoutFor(D.cases[replay.c], this.ep, rev, this.showBuffer.checked);
  };
  // A deliberate set-aside (reason "set_aside") is a decision; every other reason is an
  // invalid action after which the box is set aside.
  function stepOutcome(code) {
    var reason = D.reasons[code];
    return reason === "set_aside" ? "set aside on purpose" : "invalid (" + reason + "), set aside";
  }

  Pane.prototype.renderStrip = function () {
    var self = this;
    this.strip.innerHTML = "";
    this.ep.steps.forEach(function (st, t) {
      var d = el("div", { title: "step " + (t + 1) + (st[2] ? ": " + stepOutcome(st[2]) : ""),
        onclick: function () { self.setStep(t + 1, true); } });
      if (st[2] !== 0) d.className = "invalid";
      self.strip.appendChild(d);
    });
  };
  Pane.prototype.renderMetrics = function () {
    var x = this.ep.metrics, dl = this.metrics;
    dl.innerHTML = "";
    [["Overall", fmt(x.overall)], ["Success ratio", fmt(x.success_ratio)], ["Compactness", fmt(x.compactness)],
     ["Inside", x.inside + " / " + x.objects], ["Set aside", String(x.set_aside)],
     ["Invalid actions", String(x.invalid)], ["Max height", x.max_height_mm + " mm"],
     ["At rest when scored", x.at_rest ? "yes" : "no"], ["Policy time", fmt(x.policy_s, 3) + " s"],
    ].forEach(function (p) {
      dl.appendChild(el("dt", { text: p[0] }));
      dl.appendChild(el("dd", { text: p[1] }));
    });
  };
  Pane.prototype.setStep = function (k, fromUser) {
    if (!this.ep) return Promise.resolve();
    k = Math.min(Math.max(1, k), this.ep.steps.length);
    this.k = k;
    var done = this.draw(false);
    if (fromUser && document.getElementById("r-link").checked) {
      var other = this === state.panes["pane-a"] ? state.panes["pane-b"] : state.panes["pane-a"];
      if (other && other.ep && other.k !== k) other.setStep(k, false);
    }
    return done;
  };
  Pane.prototype.draw = function (fresh) {
    var c = D.cases[replay.c], ep = this.ep, k = this.k, st = ep.steps[k - 1];
    this.slider.value = String(k);
    this.stepLabel.textContent = "step " + k + " / " + ep.steps.length;
    Array.prototype.forEach.call(this.strip.children, function (d, t) {
      d.classList.toggle("current", t === k - 1);
    });
    var obj = st[0] >= 0 ? boxLabel(c, st[0]) : "object ?";
    var act = typeof st[1] === "string" ? st[1] :
      "object_id " + st[1][0] + ", rotation " + st[1][1] + ", cell (" + st[1][2] + ", " + st[1][3] + ")";
    this.status.className = "status" + (st[2] ? " invalid" : "");
    this.status.textContent = st[2] ?
      "Step " + k + ": " + stepOutcome(st[2]) + " (" + obj + "); action " + act :
      "Step " + k + ": placed " + obj + "; action " + act;
    var buf = this.buffer;
    buf.innerHTML = "";
    st[3].forEach(function (i) {
      var li = el("li", {}, [swatch(typeColour(i >= 0 ? c.boxes[i][3] : 0)), i >= 0 ? boxLabel(c, i) : "?"]);
      if (i === st[0]) li.className = "chosen";
      buf.appendChild(li);
    });
    var traces = sceneTraces(c, ep, k, this.view.gap, this.showBuffer.checked);
    var layout = Object.assign({}, this.view);
    delete layout.gap;
    var cfg = { responsive: true, displaylogo: false };
    return fresh ? Plotly.newPlot(this.scene, traces, layout, cfg) : Plotly.react(this.scene, traces, layout, cfg);
  };

  function renderReplayControls() {
    var cs = document.getElementById("r-case"), ss = document.getElementById("r-seed");
    D.cases.forEach(function (c, i) { cs.appendChild(option(i, c.id + " (" + c.level + ")")); });
    D.seeds.forEach(function (s) { ss.appendChild(option(s, String(s))); });
    cs.addEventListener("change", function () { openEpisode(Number(cs.value), null, null); });
    ss.addEventListener("change", function () { openEpisode(null, Number(ss.value), null); });
  }
  // Show case c, seed s (null: keep) with method m in the left pane (null: keep); the right
  // pane keeps its method unless it is the same, then takes the best other one on that case.
  function openEpisode(c, s, m) {
    if (c !== null) replay.c = c;
    if (s !== null) replay.s = s;
    var a = state.panes["pane-a"], b = state.panes["pane-b"];
    if (m !== null) a.m = m;
    if (b.m === a.m && D.methods.length > 1) {
      var best = null;
      D.methods.forEach(function (_, i) {
        var e = byKey[episodeKey(i, replay.c, replay.s)];
        if (i !== a.m && e && e.metrics && (best === null || e.metrics.overall > best[0])) best = [e.metrics.overall, i];
      });
      b.m = best ? best[1] : (a.m + 1) % D.methods.length;
    }
    document.getElementById("r-case").value = String(replay.c);
    document.getElementById("r-seed").value = String(replay.s);
    if (m !== null) document.getElementById("replay").scrollIntoView();
    return Promise.all([a.show(), b.show()]);
  }

  // For scripts (screenshots, tests): open a case by id with the methods named (by row name
  // or policy) in the left and right panes; resolves when both are drawn.
  state.open = function (caseId, seed, left, right) {
    function row(name) {
      for (var i = 0; i < D.methods.length; i++) {
        if (D.methods[i].name === name || D.methods[i].policy === name) return i;
      }
      throw new Error("no method " + name);
    }
    var c = D.cases.findIndex(function (x) { return x.id === caseId; });
    if (c < 0) throw new Error("no case " + caseId);
    if (right !== undefined && right !== null) state.panes["pane-b"].m = row(right);
    return openEpisode(c, seed === undefined || seed === null ? null : seed, left ? row(left) : null);
  };

  function initialCase() {
    for (var i = 0; i < D.cases.length; i++) if (D.cases[i].id === D.initial_case) return i;
    return 0;
  }

  function main() {
    renderHeader();
    renderResults();
    renderDetails();
    renderBrowserControls();
    renderBrowser();
    renderReplayControls();
    var jobs = [renderBoxes()];
    if (D.cases.length && D.methods.length) {
      // The best method against the best heuristic (report_data's "replay"; old pages: rows 0, 1).
      var pair = D.replay || [0, D.methods.length > 1 ? 1 : 0];
      new Pane("pane-a", pair[0]);
      new Pane("pane-b", pair[1]);
      replay.c = initialCase();
      jobs.push(openEpisode(replay.c, D.seeds[0], null));
    }
    return Promise.all(jobs);
  }

  main().then(function () {
    state.ready = true;
  }, function (err) {
    state.errors.push(String(err));
    console.error(err);
    state.ready = true;
  });
})();
