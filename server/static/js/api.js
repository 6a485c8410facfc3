// The service's /v1 API from the browser: the API key, JSON requests with {code, message}
// errors, uploads with progress, and a job's event stream that reconnects and resumes.

const KEY_STORAGE = "sparsesplat.apiKey";
const TERMINAL = new Set(["succeeded", "failed", "cancelled"]);

/** The API key of this tab ("" when none: a loopback server accepts anonymous requests). */
export function apiKey() {
  return sessionStorage.getItem(KEY_STORAGE) || "";
}

/** Keep `key` for this tab only (session storage); "" forgets it. */
export function setApiKey(key) {
  if (key) sessionStorage.setItem(KEY_STORAGE, key);
  else sessionStorage.removeItem(KEY_STORAGE);
}

export function isTerminal(state) {
  return TERMINAL.has(state);
}

/** An error answer of the API: HTTP status, stable code and a message naming the problem. */
export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

let unauthenticatedHandler = null;

/** `handler(message)` runs when the server answers 401 (missing or unknown key). */
export function onUnauthenticated(handler) {
  unauthenticatedHandler = handler;
}

function authHeaders(headers = {}) {
  const out = new Headers(headers);
  const key = apiKey();
  if (key) out.set("Authorization", `Bearer ${key}`);
  return out;
}

async function errorFrom(response) {
  let code = `http_${response.status}`;
  let message = response.statusText || `HTTP ${response.status}`;
  try {
    const body = await response.json();
    code = body.code || code;
    message = body.message || message;
  } catch {
    // not JSON: keep the status text
  }
  if (response.status === 401 && unauthenticatedHandler) unauthenticatedHandler(message);
  return new ApiError(response.status, code, message);
}

let anonymousAnswered = false;

/** Whether the server answered a /v1 request sent without a key (it runs without keys). */
export function anonymousWorks() {
  return anonymousAnswered;
}

/** GET `path` as JSON, or null on any error, without asking for a key (for a status line). */
export async function optional(path) {
  try {
    const response = await fetch(path, { headers: authHeaders() });
    return response.ok ? await response.json() : null;
  } catch {
    return null;
  }
}

/**
 * One API request. `json` is sent as the JSON body; `as` picks what comes back: "json"
 * (null for 204), "blob", "arrayBuffer" or "response".
 */
export async function request(path, { method = "GET", json, body, headers, as = "json", signal } = {}) {
  const h = authHeaders(headers);
  if (json !== undefined) {
    h.set("Content-Type", "application/json");
    body = JSON.stringify(json);
  }
  let response;
  try {
    response = await fetch(path, { method, headers: h, body, signal });
  } catch (exc) {
    if (exc.name === "AbortError") throw exc;
    throw new ApiError(0, "unreachable", `the server did not answer (${exc.message})`);
  }
  if (!response.ok) throw await errorFrom(response);
  if (!h.has("Authorization") && path.startsWith("/v1/")) anonymousAnswered = true;
  if (as === "response") return response;
  if (as === "blob") return response.blob();
  if (as === "arrayBuffer") return response.arrayBuffer();
  return response.status === 204 ? null : response.json();
}

/** GET `path` as bytes, reporting `onProgress(loaded, total)` (total 0 when unknown). */
export async function download(path, onProgress) {
  const response = await request(path, { as: "response" });
  const total = Number(response.headers.get("Content-Length") || 0);
  if (!response.body) return new Uint8Array(await response.arrayBuffer());
  const reader = response.body.getReader();
  const chunks = [];
  let loaded = 0;
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    chunks.push(value);
    loaded += value.length;
    if (onProgress) onProgress(loaded, total);
  }
  const out = new Uint8Array(loaded);
  let offset = 0;
  for (const chunk of chunks) {
    out.set(chunk, offset);
    offset += chunk.length;
  }
  return out;
}

/**
 * POST a multipart form with upload progress (fetch cannot report it). Resolves with the
 * parsed JSON answer; rejects with an ApiError.
 */
export function upload(path, form, { headers = {}, onProgress } = {}) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", path);
    for (const [name, value] of authHeaders(headers)) xhr.setRequestHeader(name, value);
    xhr.responseType = "json";
    if (onProgress) xhr.upload.onprogress = (e) => onProgress(e.loaded, e.lengthComputable ? e.total : 0);
    xhr.onerror = () => reject(new ApiError(0, "unreachable", "the upload did not reach the server"));
    xhr.onload = () => {
      const body = xhr.response || {};
      if (xhr.status >= 200 && xhr.status < 300) {
        resolve(body);
        return;
      }
      if (xhr.status === 401 && unauthenticatedHandler) unauthenticatedHandler(body.message);
      reject(new ApiError(xhr.status, body.code || `http_${xhr.status}`, body.message || xhr.statusText));
    };
    xhr.send(form);
  });
}

/**
 * A job's events over the WebSocket: every stored event once, in order, then live ones.
 * A dropped connection is reopened with `?after=<last seq seen>`, so nothing is missed and
 * nothing arrives twice. Stops after the terminal state's event.
 *
 * onEvent(event) gets {seq, type, time, data}; onStatus(status, detail) gets "connecting",
 * "live", "reconnecting", "finished" or "error".
 */
export class JobEvents {
  constructor(jobId, { after = 0, onEvent = () => {}, onStatus = () => {} } = {}) {
    this.jobId = jobId;
    this.last = after;
    this.onEvent = onEvent;
    this.onStatus = onStatus;
    this.ws = null;
    this.attempts = 0;
    this.connections = 0;
    this.finished = false;
    this.stopped = false;
    this.timer = null;
  }

  url() {
    const url = new URL(`/v1/jobs/${encodeURIComponent(this.jobId)}/events`, window.location.href);
    url.protocol = url.protocol === "https:" ? "wss:" : "ws:";
    url.searchParams.set("after", String(this.last));
    const key = apiKey();
    if (key) url.searchParams.set("access_token", key);
    return url.toString();
  }

  start() {
    this.stopped = false;
    this.connect();
    return this;
  }

  connect() {
    if (this.stopped || this.finished) return;
    this.onStatus(this.connections ? "reconnecting" : "connecting");
    const ws = new WebSocket(this.url());
    this.ws = ws;
    this.connections += 1;
    ws.onopen = () => {
      this.attempts = 0;
      this.onStatus("live");
    };
    ws.onmessage = (message) => {
      const event = JSON.parse(message.data);
      if (event.seq <= this.last) return; // never twice
      this.last = event.seq;
      if (event.type === "state" && isTerminal(event.data.state)) this.finished = true;
      this.onEvent(event);
    };
    ws.onclose = (close) => {
      if (this.ws !== ws) return;
      this.ws = null;
      if (this.stopped) return;
      if (close.code === 4401 || close.code === 4404) {
        this.finished = true;
        this.onStatus("error", close.reason || `closed (${close.code})`);
        return;
      }
      // The server closes normally (1000) only once the job is over and everything was sent.
      if (this.finished || close.code === 1000) {
        this.finished = true;
        this.onStatus("finished");
        return;
      }
      this.attempts += 1;
      const delay = Math.min(10000, 500 * 2 ** Math.min(this.attempts - 1, 5));
      this.onStatus("reconnecting", `connection lost (${close.code}); retrying in ${(delay / 1000).toFixed(1)} s`);
      this.timer = setTimeout(() => this.connect(), delay);
    };
  }

  /** Drop the current connection as a network failure would (it reconnects by itself). */
  drop() {
    if (this.ws) this.ws.close(4000, "dropped by the page");
  }

  stop() {
    this.stopped = true;
    clearTimeout(this.timer);
    if (this.ws) {
      const ws = this.ws;
      this.ws = null;
      ws.close(1000);
    }
  }
}
