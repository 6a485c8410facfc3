// The page's entry point: hash routes, the API key dialog, and the current view.
//
//   #/                  jobs: list, submit form, cancel/delete
//   #/jobs/<id>         a job: live progress, error against run time, training/held-out views
//   #/jobs/<id>/viewer  the trained model in the browser, with server renders of any pose

import { anonymousWorks, apiKey, onUnauthenticated, optional, request, setApiKey } from "./api.js";

const view = document.getElementById("view");
const keyDialog = document.getElementById("key-dialog");
const keyInput = document.getElementById("key-input");
const keyReason = document.getElementById("key-reason");
const keyButton = document.getElementById("key-button");
let current = null;
let currentHash = null;

/** Page-wide state that tests and people debugging can read from the console. */
window.sparsesplat = { route: null, view: null };

function parseRoute(hash) {
  const path = hash.replace(/^#/, "") || "/";
  let m = path.match(/^\/jobs\/([^/]+)\/viewer\/?$/);
  if (m) return { name: "viewer", jobId: decodeURIComponent(m[1]) };
  m = path.match(/^\/jobs\/([^/]+)\/?$/);
  if (m) return { name: "job", jobId: decodeURIComponent(m[1]) };
  return { name: "jobs" };
}

async function route(force = false) {
  if (!force && window.location.hash === currentHash) return;
  currentHash = window.location.hash;
  const target = parseRoute(window.location.hash);
  if (current && current.unmount) current.unmount();
  current = null;
  view.replaceChildren();
  view.dataset.view = target.name;
  window.sparsesplat.route = target;
  const modules = {
    jobs: () => import("./jobs.js"),
    job: () => import("./job.js"),
    viewer: () => import("./viewer.js"),
  };
  const module = await modules[target.name]();
  if (currentHash !== window.location.hash) return; // navigated away while loading
  current = module.mount(view, target);
  window.sparsesplat.view = current;
}

function updateKeyButton() {
  keyButton.textContent = apiKey() ? "API key ✓" : "API key";
  keyButton.title = apiKey() ? "An API key is kept in this tab" : "No API key (fine on a loopback server)";
}

function askForKey(reason) {
  if (keyDialog.open) return;
  keyReason.textContent = reason
    ? `The server says: ${reason}. Enter an API key (sparsesplat keys create NAME makes one); it is kept in this tab's session storage only.`
    : "Enter an API key (sparsesplat keys create NAME makes one); it is kept in this tab's session storage only. Without keys configured, a loopback server needs none.";
  keyInput.value = apiKey();
  keyDialog.showModal();
  keyInput.focus();
}

keyDialog.addEventListener("close", () => {
  if (keyDialog.returnValue === "save") setApiKey(keyInput.value.trim());
  else if (keyDialog.returnValue === "clear") setApiKey("");
  else return;
  updateKeyButton();
  serverStatus();
  route(true);
});
keyButton.addEventListener("click", () => askForKey(""));
onUnauthenticated((message) => askForKey(message));

const STATUS_REFRESH_MS = 15000; // the disk and the key's stored bytes change as jobs run

function megabytes(bytes) {
  return `${(bytes / 1e6).toFixed(bytes < 1e7 ? 1 : 0)} MB`;
}

async function serverStatus() {
  const box = document.getElementById("server-status");
  try {
    const health = await request("/healthz");
    const parts = [`v${health.version}`, health.device, `${health.queue} queue`];
    if (health.disk && health.disk !== "ok") {
      parts.push(`disk ${health.disk}: ${megabytes(health.disk_free_bytes)} free`);
    }
    // Only with a key, or once the server has answered without one: never a second 401.
    const usage = apiKey() || anonymousWorks() ? await optional("/v1/usage") : null;
    if (usage) {
      const limit = usage.stored_limit_bytes ? ` of ${megabytes(usage.stored_limit_bytes)}` : "";
      parts.push(`stored ${megabytes(usage.stored_bytes)}${limit}`);
    }
    box.textContent = parts.join(" · ");
  } catch (exc) {
    box.textContent = `server: ${exc.message}`;
  }
}

window.addEventListener("hashchange", () => route());
updateKeyButton();
serverStatus();
route(true);
setInterval(serverStatus, STATUS_REFRESH_MS);
