// What this tab remembers between views (never persisted): the files it uploaded per job.
//
// Photos submitted from this tab are shown from memory (no download); other jobs' photos come
// from GET /v1/jobs/{id}/images/{i}.

/** job id -> {frames: cameras.json frames in upload order, files: File per frame (or null)} */
export const uploads = new Map();
