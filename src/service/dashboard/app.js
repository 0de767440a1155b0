// The dashboard: recent jobs with live state, a job page (preview, figures, settings, links)
// and an upload form. It calls the same API as any client, with the token kept in this
// browser's localStorage when the server asks for one.
"use strict";

const $ = (id) => document.getElementById(id);
let token = localStorage.getItem("occluder-cook-token") || "";
let shown = null; // the job on the job page
let following = null; // aborts the job page's event stream

function headers(extra = {}) {
  return token ? { ...extra, Authorization: "Bearer " + token } : extra;
}

/// A fetch with the token; a 401 shows the token form.
async function api(path, options = {}) {
  const response = await fetch(path, { ...options, headers: headers(options.headers) });
  if (response.status === 401) {
    $("token-form").hidden = false;
  }
  return response;
}

async function json(path) {
  const response = await api(path);
  if (!response.ok) {
    throw new Error((await response.json().catch(() => ({}))).error?.message || response.status);
  }
  return response.json();
}

function cell(row, text) {
  const td = row.insertCell();
  td.textContent = text;
  return td;
}

function stateClass(element, state) {
  element.className = "state state-" + state;
  element.textContent = state;
}

async function refreshJobs() {
  try {
    const { jobs } = await json("/v1/jobs?limit=50");
    const body = $("jobs").tBodies[0];
    body.replaceChildren();
    for (const job of jobs) {
      const row = body.insertRow();
      row.dataset.job = job.id;
      cell(row, job.id.slice(0, 12)).title = job.id;
      cell(row, job.kind);
      stateClass(cell(row, ""), job.state);
      cell(row, Math.round(job.progress * 100) + "%" + (job.stage && job.state === "running" ? " " + job.stage : ""));
      cell(row, job.owner || "–");
      cell(row, new Date(job.created_ms).toLocaleTimeString());
      row.onclick = () => showJob(job.id);
    }
  } catch (e) {
    $("upload-status").textContent = "jobs: " + e.message;
  }
  try {
    const activity = await json("/v1/activity");
    $("queue").textContent = "queue " + activity.queue_depth;
    $("workers").textContent = `workers busy ${activity.running}/${activity.workers}`;
    $("cache").textContent = `cache ${size(activity.cache_bytes)} of ${size(activity.max_cache_bytes)}`;
  } catch (e) {
    $("queue").textContent = "queue ?";
  }
}

function size(bytes) {
  const [unit, scale] = bytes >= 2 ** 30 ? ["GiB", 2 ** 30] : bytes >= 2 ** 20 ? ["MiB", 2 ** 20] : ["KiB", 2 ** 10];
  return (bytes / scale).toFixed(bytes >= 10 * scale ? 0 : 1) + " " + unit;
}

function figure(list, name, value) {
  const dt = document.createElement("dt");
  dt.textContent = name;
  const dd = document.createElement("dd");
  dd.textContent = value;
  list.append(dt, dd);
}

/// The job page: its state as events arrive, and once done, its preview and report.
async function showJob(id) {
  location.hash = id;
  shown = id;
  $("job").hidden = false;
  $("job-id").textContent = id;
  $("job-figures").replaceChildren();
  $("preview").removeAttribute("src");
  $("links").replaceChildren();
  const job = await json("/v1/jobs/" + id);
  renderJob(job);
  if (job.state !== "done" && job.state !== "failed") {
    follow(id);
  }
}

function renderJob(job) {
  stateClass($("job-state"), job.state);
  $("job-stage").textContent = job.stage || "";
  $("job-progress").value = job.progress;
  $("job-error").textContent = job.error ? job.error.code + ": " + job.error.message : "";
  $("job-settings").textContent = JSON.stringify(job.settings, null, 2);
  if (job.state === "done") {
    showResult(job);
  }
  if (job.state === "done" || job.state === "failed") {
    refreshJobs();
  }
}

/// Reads the job's Server-Sent Events (through fetch, so that the token goes with them).
async function follow(id) {
  following?.abort();
  following = new AbortController();
  try {
    const response = await api("/v1/jobs/" + id + "/events", { signal: following.signal });
    const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
    let buffer = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done || shown !== id) break;
      buffer += value;
      let end;
      while ((end = buffer.indexOf("\n\n")) >= 0) {
        const event = buffer.slice(0, end);
        buffer = buffer.slice(end + 2);
        const data = event.split("\n").filter((l) => l.startsWith("data:")).map((l) => l.slice(5)).join("\n");
        if (data) renderJob(JSON.parse(data));
      }
    }
  } catch (e) {
    if (e.name !== "AbortError") $("job-error").textContent = "events: " + e.message;
  }
}

async function showResult(job) {
  const key = job.key;
  const links = $("links");
  if (!links.childElementCount) {
    for (const [name, path] of [["GLB", "/v1/occluders/" + key], ["report", "/v1/occluders/" + key + "/report"]]) {
      const a = document.createElement("a");
      a.textContent = name;
      a.href = path;
      a.onclick = async (event) => {
        // With a token the browser cannot follow a plain link: fetch it and hand over the bytes.
        event.preventDefault();
        const blob = await (await api(path)).blob();
        const url = URL.createObjectURL(blob);
        const download = document.createElement("a");
        download.href = url;
        download.download = name === "GLB" ? key + ".occluder.glb" : key + ".report.json";
        download.click();
        URL.revokeObjectURL(url);
      };
      links.append(a, " ");
    }
  }
  const figures = $("job-figures");
  if (!$("preview").src) {
    const sheet = (job.kind === "mesh" ? "/v1/occluders/" : "/v1/levels/") + key + "/preview.png";
    const response = await api(sheet);
    if (response.ok) $("preview").src = URL.createObjectURL(await response.blob());
  }
  if (figures.childElementCount) return;
  const report = await json("/v1/occluders/" + key + "/report");
  figure(figures, "key", key);
  if (job.kind === "mesh") {
    figure(figures, "triangles in", report.input.triangles);
    figure(figures, "triangles out", report.occluder.triangles);
    figure(figures, "pieces", `${report.occluder.boxes} boxes, ${report.occluder.quads} quads, ${report.occluder.patches} patches, ${report.occluder.surface_pieces ?? 0} surface pieces`);
    if (report.quality) {
      figure(figures, "coverage", (report.quality.coverage * 100).toFixed(1) + "%");
      figure(figures, "false pixels", report.quality.false_pixels);
    }
  } else {
    figure(figures, "instances", `${report.instances} of ${report.unique_meshes} meshes`);
    figure(figures, "triangles", `${report.triangles_before} placed -> ${report.triangles_after} occluder`);
    figure(figures, "draw calls", `${report.draw_calls_before} -> ${report.draw_calls_after}`);
    if (report.cull) {
      figure(figures, "culled", (report.cull.culled_share * 100).toFixed(1) + `% in view (${report.cull.cameras} cameras)`);
      figure(figures, "wrongly culled", report.cull.wrongly_culled);
    }
    figure(figures, "batches", report.batches.length);
    for (const batch of report.batches) {
      figure(figures, batch.name, `${batch.triangles} triangles, ${batch.instances.length} instances`);
    }
  }
  const total = Object.values(report.timings_ms || {}).reduce((a, b) => a + b, 0);
  figure(figures, "cook time", total.toFixed(0) + " ms");
  for (const note of report.notes || []) figure(figures, "note", note);
}

const types = { glb: "model/gltf-binary", gltf: "model/gltf+json", obj: "model/obj", stl: "model/stl", fbx: "model/vnd.fbx", ply: "model/x-ply" };

async function upload(event) {
  event.preventDefault();
  const file = $("file").files[0];
  if (!file) return;
  const extension = file.name.split(".").pop().toLowerCase();
  const query = new URLSearchParams({ format: extension });
  for (const name of ["resolution", "max_triangles", "device"]) {
    if ($(name).value) query.set(name, $(name).value);
  }
  $("upload-status").textContent = "uploading " + file.name + "…";
  const response = await api("/v1/cook?" + query, {
    method: "POST",
    headers: { "Content-Type": types[extension] || "application/octet-stream" },
    body: file,
  });
  const body = await response.json().catch(() => ({}));
  if (!response.ok) {
    $("upload-status").textContent = file.name + ": " + (body.error?.message || response.status);
    return;
  }
  $("upload-status").textContent = file.name + ": job " + body.job;
  await refreshJobs();
  showJob(body.job);
}

function setUp() {
  $("token-form").onsubmit = (event) => {
    event.preventDefault();
    token = $("token").value.trim();
    localStorage.setItem("occluder-cook-token", token);
    $("token-form").hidden = true;
    refreshJobs();
  };
  $("file").onchange = () => ($("submit").disabled = !$("file").files.length);
  const drop = $("drop");
  drop.ondragover = (event) => {
    event.preventDefault();
    drop.classList.add("over");
  };
  drop.ondragleave = () => drop.classList.remove("over");
  drop.ondrop = (event) => {
    event.preventDefault();
    drop.classList.remove("over");
    $("file").files = event.dataTransfer.files;
    $("submit").disabled = !$("file").files.length;
  };
  $("upload").onsubmit = upload;
  $("close").onclick = (event) => {
    event.preventDefault();
    following?.abort();
    shown = null;
    $("job").hidden = true;
    history.replaceState(null, "", location.pathname);
  };
  refreshJobs();
  setInterval(refreshJobs, 2000);
  if (location.hash.length > 1) showJob(location.hash.slice(1));
}

setUp();
