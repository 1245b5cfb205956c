// vint dashboard: reads the coordinator's dashboard views (GET /dashboard/api/...) and refreshes them
// every few seconds; the charts are SVG drawn by the coordinator (GET /dashboard/chart/NAME.svg).
// Every shown value keeps the view's own value in data-value, so a test can compare the page with
// the views.
"use strict";

const params = new URLSearchParams(window.location.search);
// ?refresh=MS: 0 stops refreshing; otherwise at most once a second (the coordinator keeps each
// view for 2 s anyway), at least every 10 minutes; anything unreadable means the default, 2 s.
const refreshMs = ((asked) => {
  if (asked === 0) return 0;
  if (!Number.isFinite(asked) || asked < 0) return 2000;
  return Math.min(Math.max(asked, 1000), 600000);
})(Number(params.get("refresh") ?? "2000"));
let jobId = params.get("job");

async function getJson(path) {
  const response = await fetch(path, { cache: "no-store" });
  if (!response.ok) {
    throw new Error(`${path}: ${response.status} ${await response.text()}`);
  }
  return response.json();
}

function element(tag, attrs = {}, text = null) {
  const el = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs)) {
    el.setAttribute(name, value);
  }
  if (text !== null) {
    el.textContent = text;
  }
  return el;
}

// How a value is shown: times as UTC clock times, reals to 3 decimals, the rest as they are.
function shown(column, value) {
  if (value === null) {
    return "";
  }
  if (column.endsWith("_ms") && typeof value === "number") {
    return new Date(value).toISOString().replace("T", " ").replace(/\.\d+Z$/, "Z");
  }
  if (typeof value === "number" && !Number.isInteger(value)) {
    return value.toFixed(3);
  }
  return String(value);
}

function renderTable(container, table) {
  const out = element("table", { "data-view": table.view });
  const head = element("tr");
  const hidden = new Set(container.dataset.table === "workers" ? [] : ["job_id"]);
  const columns = table.columns.map((name, i) => [name, i]).filter(([name]) => !hidden.has(name));
  for (const [name] of columns) {
    head.appendChild(element("th", {}, name));
  }
  out.appendChild(element("thead")).appendChild(head);
  const body = out.appendChild(element("tbody"));
  for (const row of table.rows) {
    const tr = element("tr");
    for (const [name, i] of columns) {
      const value = row[i];
      const attrs = { "data-col": name, "data-value": value === null ? "null" : String(value) };
      if (typeof value === "number") {
        attrs.class = "num";
      }
      tr.appendChild(element("td", attrs, shown(name, value)));
    }
    body.appendChild(tr);
  }
  container.replaceChildren(table.rows.length ? out : element("p", { class: "empty" }, "no rows yet"));
}

function renderJobs(jobs, progress) {
  const totals = new Map();
  for (const row of progress.rows) {
    const [job, , tasks, , , , succeeded] = row;
    const t = totals.get(job) ?? { tasks: 0, succeeded: 0 };
    t.tasks += tasks;
    t.succeeded += succeeded;
    totals.set(job, t);
  }
  const table = element("table", { "data-view": "jobs" });
  const head = element("tr");
  for (const name of ["job", "name", "state", "created", "tasks", "succeeded", "progress"]) {
    head.appendChild(element("th", {}, name));
  }
  table.appendChild(element("thead")).appendChild(head);
  const body = table.appendChild(element("tbody"));
  for (const job of jobs) {
    const t = totals.get(job.id) ?? { tasks: 0, succeeded: 0 };
    const tr = element("tr", { "data-job": job.id, class: job.id === jobId ? "selected" : "" });
    const link = element("a", { href: `?job=${encodeURIComponent(job.id)}` }, job.id);
    tr.appendChild(element("td", { "data-col": "job_id", "data-value": job.id })).appendChild(link);
    tr.appendChild(element("td", { "data-col": "name", "data-value": job.name }, job.name));
    tr.appendChild(element("td", { "data-col": "state", "data-value": job.state }, job.state));
    tr.appendChild(element("td", { "data-col": "created_ms", "data-value": String(job.created_ms) },
      shown("created_ms", job.created_ms)));
    tr.appendChild(element("td", { "data-col": "tasks", "data-value": String(t.tasks), class: "num" }, String(t.tasks)));
    tr.appendChild(element("td", { "data-col": "succeeded", "data-value": String(t.succeeded), class: "num" },
      String(t.succeeded)));
    const share = t.tasks ? t.succeeded / t.tasks : 0;
    const bar = element("div", { class: "bar", title: `${(100 * share).toFixed(1)} %` });
    bar.appendChild(element("div", { style: `width: ${(100 * share).toFixed(1)}%` }));
    tr.appendChild(element("td")).appendChild(bar);
    body.appendChild(tr);
  }
  const container = document.getElementById("jobs");
  container.replaceChildren(jobs.length ? table : element("p", { class: "empty" }, "no jobs yet"));
}

async function refresh() {
  const status = document.getElementById("status");
  try {
    const [jobs, progress] = await Promise.all([
      getJson("/dashboard/api/jobs"),
      getJson("/dashboard/api/view/job_progress"),
    ]);
    if (!jobId && jobs.length) {
      jobId = jobs[0].id;
    }
    renderJobs(jobs, progress);
    if (jobId) {
      document.getElementById("job-title").textContent = jobId;
      const job = `?job=${encodeURIComponent(jobId)}`;
      const containers = [...document.querySelectorAll("[data-table]")];
      const tables = await Promise.all(
        containers.map((c) => getJson(`/dashboard/api/view/${c.dataset.table}${job}`)),
      );
      containers.forEach((c, i) => renderTable(c, tables[i]));
      const stamp = Date.now();
      for (const img of document.querySelectorAll("img[data-chart]")) {
        img.onload = () => img.setAttribute("data-loaded", "1");
        img.src = `/dashboard/chart/${img.dataset.chart}.svg${job}&t=${stamp}`;
      }
    }
    status.textContent = `${jobId ?? "no job"} · updated ${new Date().toISOString().slice(11, 19)}Z`;
    status.className = "meta";
    document.body.setAttribute("data-ready", "1");
  } catch (error) {
    status.textContent = String(error);
    status.className = "meta error";
  }
  if (refreshMs > 0) {
    window.setTimeout(refresh, refreshMs);
  }
}

refresh();
