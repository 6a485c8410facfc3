// A job's page: live progress over the WebSocket (reconnecting and resuming with ?after=),
// the error-against-run-time chart, and once trained, the training and held-out views
// against the model's renders at the same cameras.

import { ApiError, JobEvents, isTerminal, request } from "./api.js";
import { pinhole } from "./cameras.js";
import { errorChart } from "./chart.js";
import { uploads } from "./session.js";
import { el, fmtNumber, fmtSeconds, fmtTime, progressBar, stateBadge, toast } from "./ui.js";

/** The job's "Views" line: the photos trained on, and those the camera estimation left out. */
export function viewsLine(job, cameras) {
  const heldOut = `${job.n_test_views} held-out`;
  const photos = (cameras && cameras.photos) || [];
  const leftOut = photos.filter((photo) => !photo.placed).length;
  if (!leftOut) return `${job.n_train_views} training, ${heldOut}`;
  const trained = photos.length - leftOut;
  return `${trained} training (${leftOut} of ${photos.length} photos left out, see below), ${heldOut}`;
}

/** Runs render requests one or two at a time (the render worker takes one at a time). */
export function renderQueue(concurrency = 2) {
  const waiting = [];
  let running = 0;
  let closed = false;
  function next() {
    while (!closed && running < concurrency && waiting.length) {
      const { task, resolve, reject } = waiting.shift();
      running += 1;
      task()
        .then(resolve, reject)
        .finally(() => {
          running -= 1;
          next();
        });
    }
  }
  return {
    push(task) {
      return new Promise((resolve, reject) => {
        waiting.push({ task, resolve, reject });
        next();
      });
    },
    close() {
      closed = true;
      waiting.length = 0;
    },
  };
}

/** POST /v1/models/{id}/render for a wire camera; resolves with an object URL of the PNG. */
export async function renderUrl(modelId, camera, urls) {
  const blob = await request(`/v1/models/${modelId}/render`, {
    method: "POST",
    json: { camera, output: "png" },
    as: "blob",
  });
  const url = URL.createObjectURL(blob);
  if (urls) urls.push(url);
  return url;
}

export function mount(container, { jobId }) {
  const urls = [];
  const queue = renderQueue(2);
  let job = null;
  let events = null;
  let modelShown = false;
  let unmounted = false;

  const title = el("h2", {}, "Job ", el("code", {}, jobId));
  const badge = el("span#job-state");
  const live = el("span#job-live.muted", {}, "");
  const actions = el("span.actions#job-actions");
  const progressBox = el("div#job-progress");
  const details = el("dl.details#job-details");
  const errorBox = el("p.error-text#job-error", { hidden: true });
  const warningBox = el("div#job-warnings", { hidden: true });
  const chartBox = el("div#job-chart.chart");
  const latest = el("table.metrics#job-latest");
  const viewsBox = el("section#job-views");

  container.append(
    el("p", {}, el("a", { href: "#/" }, "← Jobs")),
    el("section.card", {}, el("div.card-head", {}, title, badge, el("span.spacer"), live, actions), errorBox, warningBox, progressBox, details),
    el("section.card", {}, el("div.chart-row", {}, chartBox, el("div", {}, el("h3", {}, "Latest record"), latest))),
    viewsBox,
  );
  const chart = errorChart(chartBox, { width: Math.min(720, Math.max(360, container.clientWidth - 320)), height: 300 });
  renderLatest(null);

  function renderLatest(record) {
    const rows = [
      ["Iteration", record ? record.iteration : "–"],
      ["Training time", record ? fmtSeconds(record.elapsed_s) : "–"],
      ["PSNR", record && record.psnr != null ? `${fmtNumber(record.psnr)} dB` : "–"],
      ["SSIM", fmtNumber(record?.ssim, 3)],
      ["LPIPS", fmtNumber(record?.lpips, 3)],
      ["AVGE", fmtNumber(record?.avge, 3)],
      ["Gaussians", record ? record.n_gaussians.toLocaleString() : "–"],
    ];
    latest.replaceChildren(...rows.map(([k, v]) => el("tr", {}, el("th", {}, k), el("td.num", {}, v))));
  }

  function renderJob() {
    if (!job) return;
    badge.replaceChildren(stateBadge(job.state));
    errorBox.hidden = !job.error;
    errorBox.textContent = job.error || "";
    const warnings = job.warnings || [];
    warningBox.hidden = !warnings.length;
    warningBox.replaceChildren(...warnings.map((w) => el("p.warning-text", {}, `Warning: ${w}`)));
    actions.replaceChildren();
    if (!isTerminal(job.state)) actions.append(el("button.small.secondary#job-cancel", { type: "button", onclick: cancel }, "Cancel"));
    if (job.state === "succeeded") {
      actions.append(
        el("a.button.small#job-viewer", { href: `#/jobs/${job.id}/viewer` }, "Open viewer"),
        el("button.small.secondary", { type: "button", onclick: downloadPly }, "Download .ply"),
      );
    }
    actions.append(el("button.small.danger#job-delete", { type: "button", onclick: remove }, "Delete"));
    renderProgress(job.progress);
    const s = job.spec;
    const length = s.time_budget_s ? `time budget ${fmtSeconds(s.time_budget_s)}` : s.iterations ? `${s.iterations} iterations` : "the preset's length";
    const p = job.progress || {};
    const items = [
      ["Preset", `${p.preset || s.preset || "automatic"}${p.preset_reason ? ` (${p.preset_reason})` : ""}`],
      ["Depth prior", s.depth_prior || "the preset's"],
      ["Length", length],
      ["Views", viewsLine(job, p.cameras)],
      ["Submitted", fmtTime(job.created_at)],
      ["Started", fmtTime(job.started_at)],
      ["Finished", fmtTime(job.finished_at)],
      ["Attempts", String(job.attempts)],
    ];
    if (p.cameras) {
      // Cameras estimated from the photos, and how well they fit.
      const c = p.cameras;
      items.push(["Cameras", `estimated (${c.attempt}): ${c.views} photos placed, ${c.points.toLocaleString()} points, ${c.reprojection_error_px.toFixed(2)} px reprojection error, ${c.triangulation_angle_deg.toFixed(1)}° median triangulation angle`]);
      // Each photo: its matches and fit, or why it was left out.
      for (const photo of c.photos || []) {
        const fit = photo.placed
          ? `placed: ${photo.matches.toLocaleString()} matches, ${photo.points.toLocaleString()} points, ${photo.error_px != null ? photo.error_px.toFixed(2) : "?"} px error, direction ±${photo.rotation_std_deg != null ? photo.rotation_std_deg.toFixed(2) : "?"}°`
          : `left out (${photo.matches.toLocaleString()} matches): ${photo.reason || "not placed"}`;
        items.push([photo.name, fit]);
      }
    }
    if (job.state === "queued") items.unshift(["Queue", `${job.queue_position ?? "?"} job(s) ahead`]);
    details.replaceChildren(...items.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
  }

  function renderProgress(p) {
    if (!p) {
      progressBox.replaceChildren(el("p.muted", {}, job && job.state === "queued" ? "Waiting for a worker." : "No progress yet."));
      return;
    }
    progressBox.replaceChildren(
      el(
        "div.progress-line",
        {},
        progressBar(p.iteration, p.total),
        el(
          "span#job-iteration",
          {},
          `${p.iteration}${p.total != null ? `/${p.total}` : ""} iterations`,
          job && !isTerminal(job.state) && p.phase ? ` · ${p.phase}` : "",
          ` · ${fmtSeconds(p.elapsed_s)} trained`,
          job && !isTerminal(job.state) && p.eta_s != null ? ` · about ${fmtSeconds(p.eta_s)} left` : "",
        ),
      ),
    );
  }

  async function load() {
    try {
      job = await request(`/v1/jobs/${encodeURIComponent(jobId)}`);
    } catch (exc) {
      if (exc instanceof ApiError && exc.status === 404) {
        container.replaceChildren(el("p", {}, el("a", { href: "#/" }, "← Jobs")), el("p.error-text", {}, `No job ${jobId} (deleted, or another key's).`));
        return;
      }
      toast(`Job: ${exc.message}`);
      return;
    }
    if (unmounted) return;
    renderJob();
    if (job.progress && job.progress.last_record) renderLatest(job.progress.last_record);
    events = new JobEvents(jobId, { onEvent, onStatus }).start();
    window.sparsesplat.events = events;
    if (job.state === "succeeded") showModel();
  }

  function onStatus(status, detail) {
    const words = { connecting: "connecting…", live: "● live", reconnecting: "reconnecting…", finished: "", error: "" };
    live.textContent = status === "error" ? `events: ${detail}` : words[status] ?? status;
    live.title = detail || "";
    live.dataset.status = status;
  }

  async function onEvent(event) {
    if (event.type === "record") {
      chart.add(event.data);
      renderLatest(event.data);
    } else if (event.type === "progress" && job) {
      job.progress = { ...(job.progress || {}), ...event.data };
      renderProgress(job.progress);
    } else if (event.type === "state") {
      try {
        job = await request(`/v1/jobs/${encodeURIComponent(jobId)}`);
      } catch (exc) {
        if (!(exc instanceof ApiError && exc.status === 404)) toast(`Job: ${exc.message}`);
        return;
      }
      if (unmounted) return;
      renderJob();
      if (job.state === "succeeded") showModel();
    }
  }

  async function showModel() {
    if (modelShown || unmounted) return;
    modelShown = true;
    let model;
    try {
      model = await request(`/v1/models/${jobId}`);
    } catch (exc) {
      toast(`Model: ${exc.message}`);
      return;
    }
    if (unmounted) return;
    const session = uploads.get(jobId);
    const cameras = model.cameras.map((c, index) => ({ ...c, index }));
    const test = cameras.filter((c) => c.split === "test");
    const train = cameras.filter((c) => c.split !== "test");
    const photoNote = "Each photo as uploaded (GET /v1/jobs/{id}/images/{i}) beside the server's render.";
    viewsBox.replaceChildren(
      el(
        "section.card#heldout-views",
        {},
        el("h3", {}, `Held-out views against renders (${test.length})`),
        el("p.muted", {}, "Each held-out camera rendered by the server at the latest checkpoint (neural colour). ", photoNote),
        test.length ? el("div.view-grid", {}, test.map((c) => viewCard(c, session))) : el("p.muted", {}, "No held-out views were uploaded."),
      ),
      el(
        "section.card#training-views",
        {},
        el("h3", {}, `Training views (${train.length})`),
        el(
          "p.muted",
          {},
          photoNote,
          " With each, its depth prior (GET /v1/jobs/{id}/priors/{k}, near = bright) once the worker has computed it.",
        ),
        el("div.view-grid", {}, train.map((c, k) => viewCard(c, session, k, model.depth_priors || 0))),
      ),
    );
  }

  /** An <img> filled from an authenticated GET (an <img src> cannot send the API key). */
  function fetchedImage(spec, attrs, path, missing) {
    const img = el(spec, attrs);
    request(path, { as: "blob" })
      .then((blob) => {
        img.src = URL.createObjectURL(blob);
        urls.push(img.src);
      })
      .catch(() => {
        img.replaceWith(el("span.muted", {}, missing));
      });
    return img;
  }

  function viewCard(camera, session, trainIndex, depthPriors = 0) {
    const file = session && session.files[camera.index];
    const render = el("img.render", { alt: `render at camera ${camera.index}`, width: camera.width, height: camera.height, dataset: { cameraIndex: String(camera.index), split: camera.split } });
    const status = el("span.muted", {}, "rendering…");
    const size = { width: camera.width, height: camera.height };
    const photo = file
      ? el("img.photo", { alt: `photo ${file.name}`, src: URL.createObjectURL(file), ...size })
      : fetchedImage("img.photo", { alt: `photo ${camera.index}`, ...size }, `/v1/jobs/${jobId}/images/${camera.index}`, "photo unavailable");
    if (file) urls.push(photo.src);
    const prior =
      trainIndex === undefined
        ? null
        : trainIndex >= depthPriors
        ? el("span.muted", {}, "no depth prior (the preset uses none)")
        : fetchedImage("img.prior", { alt: `depth prior ${trainIndex}`, ...size }, `/v1/jobs/${jobId}/priors/${trainIndex}`, "no depth prior (the preset uses none)");
    queue
      .push(() => renderUrl(jobId, pinhole(camera), urls))
      .then((url) => {
        render.src = url;
        status.textContent = "";
        render.dataset.ready = "1";
      })
      .catch((exc) => {
        status.textContent = `render failed: ${exc.message}`;
      });
    return el(
      "figure.view-card",
      { dataset: { cameraIndex: String(camera.index), split: camera.split } },
      el(
        "div.pair",
        {},
        el("div", {}, photo, el("div.caption", {}, "photo")),
        el("div", {}, render, el("div.caption", {}, "render ", status)),
        prior ? el("div", {}, prior, el("div.caption", {}, "depth prior")) : null,
      ),
      el("figcaption", {}, `#${camera.index} ${camera.split} · ${camera.width}×${camera.height}`, file ? ` · ${file.name}` : ""),
    );
  }

  async function cancel() {
    try {
      job = await request(`/v1/jobs/${jobId}/cancel`, { method: "POST" });
      renderJob();
    } catch (exc) {
      toast(`Cancel: ${exc.message}`);
    }
  }

  async function remove() {
    if (!window.confirm(`Delete ${jobId} and every file of it?`)) return;
    try {
      if (events) events.stop();
      await request(`/v1/jobs/${jobId}`, { method: "DELETE" });
      uploads.delete(jobId);
      window.location.hash = "#/";
    } catch (exc) {
      toast(`Delete: ${exc.message}`);
    }
  }

  async function downloadPly() {
    try {
      const blob = await request(`/v1/models/${jobId}/export/ply`, { as: "blob" });
      const url = URL.createObjectURL(blob);
      el("a", { href: url, download: `${jobId}.ply` }).click();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
    } catch (exc) {
      toast(`Download: ${exc.message}`);
    }
  }

  load();
  return {
    name: "job",
    chart,
    get job() {
      return job;
    },
    get events() {
      return events;
    },
    unmount() {
      unmounted = true;
      if (events) events.stop();
      queue.close();
      chart.destroy();
      for (const url of urls) URL.revokeObjectURL(url);
    },
  };
}
