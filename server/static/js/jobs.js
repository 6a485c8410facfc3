// The jobs view: the caller's jobs (state, progress, latest held-out PSNR/LPIPS) and a form
// that starts one from dropped images + cameras.json (or a dataset folder's files).

import { isTerminal, request, upload } from "./api.js";
import { uploads } from "./session.js";
import { el, fmtBytes, fmtNumber, fmtSeconds, fmtTime, progressBar, stateBadge, toast } from "./ui.js";

const IMAGE_RE = /\.(png|jpe?g|webp)$/i;
const PAGE_SIZE = 50;

export function mount(container) {
  const list = jobList();
  const form = jobForm();
  container.append(el("div.columns", {}, list.node, form.node));
  return {
    name: "jobs",
    list,
    form,
    unmount() {
      list.stop();
    },
  };
}

// ---------------------------------------------------------------- the list

function jobList() {
  const body = el("tbody#jobs-body");
  const empty = el("p.muted#jobs-empty", { hidden: true }, "No jobs yet: start one with the form.");
  const more = el("button.secondary.small#jobs-more", { type: "button", hidden: true }, "Older jobs…");
  const stateFilter = el(
    "select#jobs-filter",
    { "aria-label": "Filter by state" },
    ["", "queued", "running", "succeeded", "failed", "cancelled"].map((s) => el("option", { value: s }, s || "all states")),
  );
  const node = el(
    "section.card.jobs",
    {},
    el("div.card-head", {}, el("h2", {}, "Jobs"), el("span.spacer"), stateFilter),
    el(
      "table.jobs-table",
      {},
      el(
        "thead",
        {},
        el("tr", {}, ["Job", "State", "Progress", "PSNR", "LPIPS", "Views", "Submitted", ""].map((h) => el("th", {}, h))),
      ),
      body,
    ),
    empty,
    more,
  );
  let timer = null;
  let stopped = false;
  let cursor = null;
  let older = [];

  async function refresh() {
    clearTimeout(timer);
    if (stopped) return;
    let active = false;
    try {
      const params = new URLSearchParams({ limit: String(PAGE_SIZE) });
      if (stateFilter.value) params.set("state", stateFilter.value);
      const page = await request(`/v1/jobs?${params}`);
      if (stopped) return;
      const jobs = [...page.jobs, ...older.filter((o) => !page.jobs.some((j) => j.id === o.id))];
      cursor = older.length ? cursor : page.next_cursor;
      render(jobs);
      active = jobs.some((j) => !isTerminal(j.state));
    } catch (exc) {
      if (!stopped) toast(`Jobs: ${exc.message}`);
    }
    if (!stopped) timer = setTimeout(refresh, active ? 2000 : 10000);
  }

  function render(jobs) {
    body.replaceChildren(...jobs.map(row));
    empty.hidden = jobs.length > 0;
    more.hidden = !cursor;
    node.dataset.count = String(jobs.length);
  }

  function row(job) {
    const p = job.progress || {};
    const record = p.last_record || {};
    let progress;
    if (job.state === "queued") progress = el("span.muted", {}, `queued, ${job.queue_position ?? "?"} ahead`);
    else if (job.progress) {
      progress = el(
        "span.progress-cell",
        {},
        progressBar(p.iteration, p.total),
        el("span.muted", {}, `${p.iteration ?? 0}${p.total != null ? `/${p.total}` : " iterations"}${job.state === "running" && p.phase ? ` · ${p.phase}` : ""}`),
        job.state === "running" && p.eta_s != null ? el("span.muted", {}, ` · ${fmtSeconds(p.eta_s)} left`) : null,
      );
    } else progress = el("span.muted", {}, "–");
    const actions = el("span.actions");
    if (!isTerminal(job.state)) {
      actions.append(el("button.small.secondary", { type: "button", onclick: () => act(job, "cancel") }, "Cancel"));
    }
    if (job.state === "succeeded") {
      actions.append(el("a.button.small", { href: `#/jobs/${job.id}/viewer` }, "Viewer"));
    }
    actions.append(el("button.small.danger", { type: "button", onclick: () => act(job, "delete") }, "Delete"));
    return el(
      "tr",
      { dataset: { jobId: job.id, state: job.state } },
      el("td", {}, el("a", { href: `#/jobs/${job.id}` }, job.id)),
      el("td", { title: job.error || "" }, stateBadge(job.state), job.error ? el("div.error-text", {}, job.error) : null),
      el("td", {}, progress),
      el("td.num", {}, record.psnr != null ? `${fmtNumber(record.psnr)} dB` : "–"),
      el("td.num", {}, fmtNumber(record.lpips, 3)),
      el("td.num", {}, `${job.n_train_views} + ${job.n_test_views}`),
      el("td", {}, fmtTime(job.created_at)),
      el("td", {}, actions),
    );
  }

  async function act(job, action) {
    try {
      if (action === "cancel") {
        await request(`/v1/jobs/${job.id}/cancel`, { method: "POST" });
        toast(`Cancelling ${job.id}`, "info");
      } else {
        if (!window.confirm(`Delete ${job.id} and every file of it (model, exports, uploads)?`)) return;
        await request(`/v1/jobs/${job.id}`, { method: "DELETE" });
        uploads.delete(job.id);
        older = older.filter((o) => o.id !== job.id);
        toast(`Deleted ${job.id}`, "info");
      }
    } catch (exc) {
      toast(`${action} ${job.id}: ${exc.message}`);
    }
    refresh();
  }

  more.addEventListener("click", async () => {
    if (!cursor) return;
    const params = new URLSearchParams({ limit: String(PAGE_SIZE), cursor });
    if (stateFilter.value) params.set("state", stateFilter.value);
    try {
      const page = await request(`/v1/jobs?${params}`);
      older = [...older, ...page.jobs];
      cursor = page.next_cursor;
      refresh();
    } catch (exc) {
      toast(`Jobs: ${exc.message}`);
    }
  });
  stateFilter.addEventListener("change", () => {
    older = [];
    cursor = null;
    refresh();
  });
  refresh();
  return {
    node,
    refresh,
    stop() {
      stopped = true;
      clearTimeout(timer);
    },
  };
}

// ---------------------------------------------------------------- the form

function randomKey() {
  const bytes = crypto.getRandomValues(new Uint8Array(16));
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}

function baseName(path) {
  return path.replace(/\\/g, "/").split("/").pop();
}

function relativePath(file) {
  return file.webkitRelativePath || file._relativePath || file.name;
}

/** The file for `path` (a frame's image or depth entry): same name, preferring the same folders. */
function findFile(files, path) {
  const name = baseName(path);
  const candidates = files.filter((f) => f.name === name);
  return candidates.find((f) => relativePath(f).replace(/\\/g, "/").endsWith(path.replace(/^\.\//, ""))) || candidates[0] || null;
}

/** Files of dropped folders, recursively (DataTransfer entries). */
async function filesFromDrop(dataTransfer) {
  const entries = Array.from(dataTransfer.items || [])
    .map((item) => (item.webkitGetAsEntry ? item.webkitGetAsEntry() : null))
    .filter(Boolean);
  if (!entries.length) return Array.from(dataTransfer.files || []);
  const out = [];
  async function walk(entry, prefix) {
    if (entry.isFile) {
      const file = await new Promise((resolve, reject) => entry.file(resolve, reject));
      file._relativePath = prefix + file.name;
      out.push(file);
    } else if (entry.isDirectory) {
      const reader = entry.createReader();
      for (;;) {
        const batch = await new Promise((resolve, reject) => reader.readEntries(resolve, reject));
        if (!batch.length) break;
        for (const child of batch) await walk(child, `${prefix}${entry.name}/`);
      }
    }
  }
  for (const entry of entries) await walk(entry, "");
  return out;
}

function jobForm() {
  let files = [];
  let plan = null;
  const fileInput = el("input#job-files", { type: "file", multiple: true, hidden: true, accept: ".json,.png,.jpg,.jpeg,.webp,.npy,image/*,application/json" });
  const folderInput = el("input#job-folder", { type: "file", multiple: true, hidden: true, webkitdirectory: true });
  const summary = el("div#upload-summary.muted", {}, "No files yet.");
  const drop = el(
    "div.dropzone#dropzone",
    { tabindex: "0" },
    el("p", {}, "Drop images and their ", el("code", {}, "cameras.json"), " here, or a dataset folder."),
    el(
      "p",
      {},
      el("button.secondary.small", { type: "button", onclick: () => fileInput.click() }, "Choose files"),
      " ",
      el("button.secondary.small", { type: "button", onclick: () => folderInput.click() }, "Choose folder"),
    ),
    fileInput,
    folderInput,
  );
  const preset = el(
    "select#job-preset",
    { name: "preset" },
    el("option", { value: "" }, "automatic (from the images)"),
    el("option", { value: "llff" }, "llff: forward-facing capture"),
    el("option", { value: "dtu" }, "dtu: object on a dark background"),
    el("option", { value: "blender" }, "blender: object on white"),
    el("option", { value: "default" }, "default: user upload (LLFF recipe)"),
  );
  const prior = el(
    "select#job-prior",
    { name: "depth_prior" },
    el("option", { value: "" }, "the preset's"),
    el("option", { value: "pydnet" }, "pydnet (bundled monocular)"),
    el("option", { value: "plane_sweep" }, "plane_sweep (geometric)"),
    el("option", { value: "user" }, "uploaded depth maps"),
    el("option", { value: "none" }, "none"),
    el("option", { value: "custom" }, "ONNX model on the server…"),
  );
  const priorCustom = el("input#job-prior-custom", { type: "text", placeholder: "onnx:NAME", hidden: true, size: 16 });
  const length = el(
    "select#job-length",
    { name: "length" },
    el("option", { value: "budget" }, "time budget (seconds)"),
    el("option", { value: "iterations" }, "iterations"),
    el("option", { value: "preset" }, "the preset's default"),
  );
  const lengthValue = el("input#job-length-value", { type: "number", min: "1", step: "any", value: "600" });
  const interval = el("input#job-record-interval", { type: "number", min: "0.1", step: "any", placeholder: "preset's (60)" });
  const seed = el("input#job-seed", { type: "number", min: "0", step: "1", value: "0" });
  const submit = el("button#job-submit", { type: "submit", disabled: true }, "Start training");
  const sent = el("progress#job-upload-progress", { hidden: true, max: 1 });
  const node = el(
    "form.card.job-form#job-form",
    { novalidate: true },
    el("h2", {}, "New job"),
    drop,
    summary,
    el(
      "div.fields",
      {},
      el("label", {}, "Preset", preset),
      el("label", {}, "Depth prior", el("span.inline", {}, prior, priorCustom)),
      el("label", {}, "Length", el("span.inline", {}, length, lengthValue)),
      el("label", {}, "Record every (s)", interval),
      el("label", {}, "Seed", seed),
    ),
    el("div.form-actions", {}, submit, sent),
  );

  prior.addEventListener("change", () => {
    priorCustom.hidden = prior.value !== "custom";
  });
  length.addEventListener("change", () => {
    lengthValue.hidden = length.value === "preset";
    if (length.value === "iterations" && Number(lengthValue.value) < 10) lengthValue.value = "2000";
  });

  async function addFiles(newFiles) {
    const byPath = new Map(files.map((f) => [relativePath(f), f]));
    for (const f of newFiles) byPath.set(relativePath(f), f);
    files = Array.from(byPath.values());
    await plan_();
  }

  async function plan_() {
    plan = null;
    submit.disabled = true;
    const jsons = files.filter((f) => f.name.toLowerCase().endsWith(".json"));
    const camerasFile =
      jsons.filter((f) => f.name === "cameras.json").sort((a, b) => relativePath(a).length - relativePath(b).length)[0] ||
      (jsons.length === 1 ? jsons[0] : null);
    const images = files.filter((f) => IMAGE_RE.test(f.name));
    if (!camerasFile) {
      summary.replaceChildren(
        `${images.length} image(s); `,
        el("strong", {}, "no cameras.json yet"),
        " (it lists each image with its pose: see docs/cameras.md).",
      );
      return;
    }
    let cameras;
    try {
      cameras = JSON.parse(await camerasFile.text());
    } catch (exc) {
      summary.replaceChildren(el("strong.error-text", {}, `${relativePath(camerasFile)} is not valid JSON: ${exc.message}`));
      return;
    }
    const frames = Array.isArray(cameras.frames) ? cameras.frames : [];
    if (!frames.length) {
      summary.replaceChildren(el("strong.error-text", {}, `${relativePath(camerasFile)} has no "frames" list.`));
      return;
    }
    const matched = frames.map((f) => (typeof f.image === "string" ? findFile(images, f.image) : null));
    const missing = frames.filter((f, i) => !matched[i]).map((f) => f.image);
    const depths = frames.map((f) => (typeof f.depth === "string" ? findFile(files, f.depth) : null));
    const missingDepth = frames.filter((f, i) => typeof f.depth === "string" && !depths[i]).map((f) => f.depth);
    const masks = frames.map((f) => (typeof f.mask === "string" ? findFile(files, f.mask) : null));
    const missingMask = frames.filter((f, i) => typeof f.mask === "string" && !masks[i]).map((f) => f.mask);
    const used = new Set([...matched, ...depths, ...masks].filter(Boolean));
    const unused = images.filter((f) => !used.has(f));
    const nTest = frames.filter((f) => f.split === "test").length;
    const bytes = [camerasFile, ...used].reduce((s, f) => s + f.size, 0);
    // replaceChildren turns a null argument into the text "null": keep only the lines shown.
    const lines = [
      el(
        "p",
        {},
        `${relativePath(camerasFile)}: ${frames.length} frames (${frames.length - nTest} training, ${nTest} held-out), `,
        `convention ${cameras.convention ?? "?"}, pose ${cameras.pose ?? "?"}; ${fmtBytes(bytes)} to upload.`,
      ),
      missing.length ? el("p.error-text", {}, `Missing image(s): ${missing.slice(0, 8).join(", ")}${missing.length > 8 ? "…" : ""}`) : null,
      missingDepth.length ? el("p.error-text", {}, `Missing depth map(s): ${missingDepth.slice(0, 8).join(", ")}`) : null,
      missingMask.length ? el("p.error-text", {}, `Missing mask(s): ${missingMask.slice(0, 8).join(", ")}`) : null,
      unused.length ? el("p.muted", {}, `Not in cameras.json (left out): ${unused.slice(0, 8).map((f) => f.name).join(", ")}${unused.length > 8 ? "…" : ""}`) : null,
    ];
    summary.replaceChildren(...lines.filter(Boolean));
    if (missing.length || missingDepth.length || missingMask.length) return;
    plan = { camerasFile, cameras, frames, matched, depths, masks };
    submit.disabled = false;
  }

  function spec() {
    const out = {};
    if (preset.value) out.preset = preset.value;
    const p = prior.value === "custom" ? priorCustom.value.trim() : prior.value;
    if (p) out.depth_prior = p;
    const n = Number(lengthValue.value);
    if (length.value === "iterations" && n > 0) out.iterations = Math.round(n);
    if (length.value === "budget" && n > 0) out.time_budget_s = n;
    if (interval.value && Number(interval.value) > 0) out.eval_interval_s = Number(interval.value);
    if (seed.value) out.seed = Math.max(0, Math.round(Number(seed.value)));
    return out;
  }

  node.addEventListener("submit", async (event) => {
    event.preventDefault();
    if (!plan) return;
    const form = new FormData();
    form.append("cameras", plan.camerasFile, "cameras.json");
    plan.matched.forEach((f) => form.append("images", f, f.name));
    plan.depths.forEach((f) => f && form.append("depths", f, f.name));
    plan.masks.forEach((f) => f && form.append("masks", f, f.name));
    form.append("spec", JSON.stringify(spec()));
    submit.disabled = true;
    sent.hidden = false;
    sent.value = 0;
    try {
      const job = await upload("/v1/jobs", form, {
        headers: { "Idempotency-Key": randomKey() },
        onProgress: (loaded, total) => {
          if (total) sent.value = loaded / total;
        },
      });
      uploads.set(job.id, { frames: plan.frames, files: plan.matched });
      toast(`Submitted ${job.id}`, "info");
      window.location.hash = `#/jobs/${job.id}`;
    } catch (exc) {
      toast(`Not submitted: ${exc.message}`);
      submit.disabled = false;
    } finally {
      sent.hidden = true;
    }
  });

  fileInput.addEventListener("change", () => addFiles(Array.from(fileInput.files)));
  folderInput.addEventListener("change", () => {
    files = [];
    addFiles(Array.from(folderInput.files));
  });
  for (const name of ["dragenter", "dragover"]) {
    drop.addEventListener(name, (e) => {
      e.preventDefault();
      drop.classList.add("over");
    });
  }
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", async (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    addFiles(await filesFromDrop(e.dataTransfer));
  });
  drop.addEventListener("keydown", (e) => {
    if (e.key === "Enter" || e.key === " ") fileInput.click();
  });
  return { node, spec, addFiles, get plan() { return plan; } };
}
