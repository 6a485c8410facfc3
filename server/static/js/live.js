// The live view: camera poses to the server over a WebSocket (/v1/models/{id}/live), server
// renders (the neural colour, exactly) back as they are ready. The server renders one pose at
// a time and only the newest waiting one, so the view follows the camera without a backlog;
// here a frame older than MAX_FRAME_AGE_MS is not shown (a newer one is on its way), except
// the answer to the last pose sent, which is the still view.

import { apiKey } from "./api.js";

/** Frames older than this (pose sent to frame decoded) are skipped while the camera moves. */
export const MAX_FRAME_AGE_MS = 300;
/** Milliseconds between reconnection attempts after the connection dropped. */
const RETRY_MS = 1000;
/** Ages of the frames shown while moving, kept for the page's statistics (a sliding window). */
const AGE_WINDOW = 600;

/** The current time in ms on the clock the pose timestamps use (echoed by the server). */
function now() {
  return performance.timeOrigin + performance.now();
}

/** Header and image of a binary frame: 4-byte big-endian header length, header JSON, image. */
export function parseFrame(buffer) {
  const n = new DataView(buffer).getUint32(0, false);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, n)));
  return { header, image: new Uint8Array(buffer, 4 + n) };
}

export class LiveView {
  /**
   * onFrame(bitmap, header) is called with each frame to show, decoded (header: the server's
   * LiveFrame plus `age`, ms from the pose to now, and `still`, whether it answers the last
   * pose sent); onStatus(text) with "connecting", "live", "closed: …" or an error.
   */
  constructor(modelId, { onFrame = () => {}, onStatus = () => {}, output = "jpeg", quality = 85 } = {}) {
    this.modelId = modelId;
    this.onFrame = onFrame;
    this.onStatus = onStatus;
    this.options = { output, quality, mode: "neural" };
    this.ws = null;
    this.stopped = false;
    this.retryAt = 0; // no reconnection before this (performance.now() ms)
    this.pending = null; // a pose to send once the socket opens
    this.lastSent = null; // t of the last pose sent
    this.shownSeq = 0;
    this.lastFrame = null; // {header, bytes} of the last frame shown (for tests)
    this.stats = { sent: 0, received: 0, shown: 0, still: 0, skipped: 0, ages: [], errors: 0 };
  }

  socketUrl() {
    const url = new URL(`/v1/models/${encodeURIComponent(this.modelId)}/live`, window.location.href);
    url.protocol = url.protocol === "https:" ? "wss:" : "ws:";
    const key = apiKey();
    if (key) url.searchParams.set("access_token", key);
    return url.toString();
  }

  start() {
    if (this.ws) return this;
    this.stopped = false;
    this.onStatus("connecting");
    const ws = new WebSocket(this.socketUrl());
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    ws.onopen = () => {
      this.onStatus("live");
      if (this.pending) this.send(this.pending.camera, this.pending.extra);
      this.pending = null;
    };
    ws.onmessage = (message) => this.receive(message.data);
    ws.onclose = (close) => {
      if (this.ws !== ws) return;
      this.ws = null;
      // No key, no such model, no model yet: reconnecting cannot help.
      if ([4401, 4404, 4409].includes(close.code)) this.stopped = true;
      this.retryAt = performance.now() + RETRY_MS;
      this.onStatus(`closed: ${close.reason || close.code}`);
    };
    return this;
  }

  stop() {
    this.stopped = true;
    const ws = this.ws;
    this.ws = null;
    if (ws) ws.close(1000);
  }

  /** Ask for a render of `camera` (a wire PinholeCamera), with `extra` pose fields (e.g.
   * `downscale`); replaces any pose not yet sent. */
  send(camera, extra = {}) {
    // A dropped connection (a render worker restarting, a network blip) is reopened by the
    // next camera move.
    if (!this.ws && !this.stopped && performance.now() >= this.retryAt) this.start();
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) {
      this.pending = { camera, extra };
      return;
    }
    const t = now();
    this.lastSent = t;
    this.stats.sent += 1;
    this.ws.send(JSON.stringify({ camera, t, ...this.options, ...extra }));
  }

  async receive(data) {
    if (typeof data === "string") {
      const error = JSON.parse(data);
      this.stats.errors += 1;
      this.onStatus(`error: ${error.message}`);
      return;
    }
    const { header, image } = parseFrame(data);
    const stats = this.stats;
    stats.received += 1;
    const still = header.t === this.lastSent; // the answer to the last pose: the still view
    if (!still && now() - header.t > MAX_FRAME_AGE_MS) {
      stats.skipped += 1;
      return;
    }
    this.lastFrame = { header, bytes: image };
    const bitmap = await createImageBitmap(new Blob([image], { type: header.media }));
    if (!this.ws) return;
    // Age when ready to draw: pose sent -> render -> transfer -> decoded.
    const age = now() - header.t;
    if ((!still && age > MAX_FRAME_AGE_MS) || header.seq <= this.shownSeq) {
      stats.skipped += 1; // too old by now, or a later frame was decoded first
      bitmap.close();
      return;
    }
    this.shownSeq = header.seq;
    stats.shown += 1;
    if (still) stats.still += 1;
    else stats.ages.push(age);
    if (stats.ages.length > AGE_WINDOW) stats.ages.shift();
    this.onFrame(bitmap, { ...header, age, still });
  }
}
