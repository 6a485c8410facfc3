// What this tab remembers between views (never persisted): the files it uploaded per job.
//
// The API does not serve a job's uploaded images back, so the job page shows the photos
// beside their renders only for jobs submitted from this tab; other jobs show the renders.

/** job id -> {frames: cameras.json frames in upload order, files: File per frame (or null)} */
export const uploads = new Map();
