// Cameras between the page and the API.
//
// The API has one camera on the wire, api/cameras.py's PinholeCamera: `convention` (opencv:
// +x right, +y down, +z forward | opengl: +x right, +y up, +z back), `pose` (camera_to_world |
// world_to_camera), a row-major rigid 4x4 `matrix`, fx fy cx cy in pixels (pixel centres at
// +0.5) and width height. three.js cameras are OpenGL-style: `camera.matrixWorld` is the
// camera-to-world in OpenGL axes (looking down -z), stored column-major. So the page sends
// {convention: "opengl", pose: "camera_to_world", matrix: matrixWorld transposed} and the
// intrinsics of its canvas; tests/web check that a world point lands on the same pixel in
// three.js and in the API's own conversion.
//
// Pure functions (no three.js import): three.js objects are only read and written through
// their own methods.

export const PINHOLE_FIELDS = ["convention", "pose", "matrix", "fx", "fy", "cx", "cy", "width", "height"];

/** The PinholeCamera fields of a camera as GET /v1/models/{id} lists it (drops image, split…). */
export function pinhole(frame) {
  const out = {};
  for (const name of PINHOLE_FIELDS) out[name] = frame[name];
  return out;
}

/** Inverse of a rigid row-major 4x4 [R t; 0 1]: [R^T, -R^T t; 0 1]. */
export function rigidInverse(m) {
  const r = [0, 1, 2].map((i) => [0, 1, 2].map((j) => m[j][i]));
  const t = [0, 1, 2].map((i) => -(r[i][0] * m[0][3] + r[i][1] * m[1][3] + r[i][2] * m[2][3]));
  return [[...r[0], t[0]], [...r[1], t[1]], [...r[2], t[2]], [0, 0, 0, 1]];
}

/** A camera's pose as camera-to-world in OpenGL axes (what three.js's matrixWorld holds). */
export function openglCameraToWorld(camera) {
  let m = camera.matrix.map((row) => [...row]);
  if (camera.pose === "world_to_camera") m = rigidInverse(m);
  else if (camera.pose !== "camera_to_world") throw new Error(`unknown pose ${camera.pose}`);
  if (camera.convention === "opencv") {
    // OpenCV camera axes = OpenGL axes with y and z negated: c2w_gl = c2w_cv · diag(1,-1,-1,1).
    m = m.map((row) => [row[0], -row[1], -row[2], row[3]]);
  } else if (camera.convention !== "opengl") {
    throw new Error(`unknown convention ${camera.convention}`);
  }
  return m;
}

/** Row-major nested 4x4 of a three.js Matrix4 (whose `elements` are column-major). */
export function rowMajor(matrix4) {
  const e = matrix4.elements;
  const rows = [0, 1, 2, 3].map((i) => [0, 1, 2, 3].map((j) => e[j * 4 + i]));
  rows[3] = [0, 0, 0, 1]; // exact: the API refuses anything else
  return rows;
}

/** Camera centre and unit viewing direction (world) of a wire camera. */
export function centreAndForward(camera) {
  const m = openglCameraToWorld(camera);
  const centre = [m[0][3], m[1][3], m[2][3]];
  const forward = [-m[0][2], -m[1][2], -m[2][2]];
  const up = [m[0][1], m[1][1], m[2][1]];
  return { centre, forward, up };
}

/** Focal length in pixels of a three.js PerspectiveCamera drawn `height` pixels high. */
export function focalPixels(fovDegrees, height) {
  return (0.5 * height) / Math.tan((fovDegrees * Math.PI) / 360);
}

/**
 * The PinholeCamera seeing exactly what a three.js PerspectiveCamera draws on a
 * `width` x `height` canvas (no zoom, no view offset; aspect = width / height, so the pixels
 * are square and the principal point is the canvas centre).
 */
export function threeCameraToPinhole(camera, width, height) {
  camera.updateMatrixWorld(true);
  const f = focalPixels(camera.fov, height) * camera.zoom;
  return {
    convention: "opengl",
    pose: "camera_to_world",
    matrix: rowMajor(camera.matrixWorld),
    fx: f,
    fy: f,
    cx: width / 2,
    cy: height / 2,
    width,
    height,
  };
}

/**
 * Put a three.js PerspectiveCamera (child of the scene root) at a wire camera's pose, with its
 * vertical field of view. The canvas keeps its own aspect; a principal point off the image
 * centre is not reproduced (the server render of a pinned camera uses the camera as given).
 */
export function placeThreeCamera(camera, wire) {
  const m = openglCameraToWorld(wire);
  camera.matrix.set(...m.flat());
  camera.matrix.decompose(camera.position, camera.quaternion, camera.scale);
  camera.scale.set(1, 1, 1);
  camera.fov = (2 * Math.atan((0.5 * wire.height) / wire.fy) * 180) / Math.PI;
  camera.zoom = 1;
  camera.updateProjectionMatrix();
  camera.updateMatrixWorld(true);
}

/**
 * The point nearest every camera's optical axis (least squares), the scene's natural orbit
 * centre for captures looking inward; for near-parallel axes (forward-facing captures) the
 * solution is pulled towards a point ahead of the cameras. Also a length scale: the median
 * camera distance to it.
 */
export function orbitCentre(cameras) {
  const axes = cameras.map(centreAndForward);
  const mean = [0, 1, 2].map((k) => axes.reduce((s, a) => s + a.centre[k], 0) / axes.length);
  const spread = Math.max(
    1e-6,
    Math.sqrt(axes.reduce((s, a) => s + a.centre.reduce((t, c, k) => t + (c - mean[k]) ** 2, 0), 0) / axes.length),
  );
  const meanFwd = [0, 1, 2].map((k) => axes.reduce((s, a) => s + a.forward[k], 0) / axes.length);
  const prior = mean.map((c, k) => c + meanFwd[k] * spread * 2);
  const lambda = 1e-3 * axes.length;
  // Sum over cameras of (I - d d^T) (x - c) = 0, plus lambda (x - prior).
  const A = [[lambda, 0, 0], [0, lambda, 0], [0, 0, lambda]];
  const b = prior.map((p) => lambda * p);
  for (const { centre, forward: d } of axes) {
    for (let i = 0; i < 3; i++) {
      for (let j = 0; j < 3; j++) {
        const p = (i === j ? 1 : 0) - d[i] * d[j];
        A[i][j] += p;
        b[i] += p * centre[j];
      }
    }
  }
  const x = solve3(A, b);
  const distances = axes.map((a) => Math.hypot(...a.centre.map((c, k) => c - x[k]))).sort((p, q) => p - q);
  const scale = distances[Math.floor(distances.length / 2)] || 1;
  const up = [0, 1, 2].map((k) => axes.reduce((s, a) => s + a.up[k], 0));
  const norm = Math.hypot(...up) || 1;
  return { centre: x, scale, up: up.map((u) => u / norm) };
}

function solve3(A, b) {
  const det = (m) =>
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
    m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
    m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  const d = det(A);
  return [0, 1, 2].map((k) => det(A.map((row, i) => row.map((v, j) => (j === k ? b[i] : v)))) / d);
}

/** Largest angle (radians) between a camera's axis and the mean axis for a capture to count as
 * forward-facing: LLFF-style captures stay within a few degrees; inward orbits spread wide. */
export const FORWARD_FACING_SPREAD = (25 * Math.PI) / 180;
/** Smallest margin (radians) the orbit may go beyond the captured cone on each side. */
export const CONE_MARGIN = (10 * Math.PI) / 180;

/**
 * Whether the cameras face one way (an LLFF-style capture): every axis within
 * FORWARD_FACING_SPREAD of their mean. Such a capture has nothing to show far outside the cone
 * the cameras span (a drag of the full canvas used to turn the view black); a capture around
 * the object may be orbited freely.
 */
export function isForwardFacing(cameras) {
  const axes = cameras.map(centreAndForward);
  const mean = normalise([0, 1, 2].map((k) => axes.reduce((s, a) => s + a.forward[k], 0)));
  return axes.every((a) => Math.acos(Math.min(1, Math.max(-1, dot(a.forward, mean)))) <= FORWARD_FACING_SPREAD);
}

/**
 * The orbit a forward-facing capture allows, from the cameras' offsets to the orbit target
 * already in the orbit frame of three.js's OrbitControls (up = +y; azimuth atan2(x, z), polar
 * acos(y / r)): the cameras' azimuth and polar ranges, each widened by half its span (at least
 * CONE_MARGIN) on each side.
 */
export function coneRanges(offsets) {
  const theta = offsets.map((o) => Math.atan2(o[0], o[2]));
  const phi = offsets.map((o) => Math.acos(Math.min(1, Math.max(-1, o[1] / Math.hypot(...o)))));
  // Azimuths relative to their circular mean, so a cone across +-pi stays one interval.
  const centre = Math.atan2(theta.reduce((s, t) => s + Math.sin(t), 0), theta.reduce((s, t) => s + Math.cos(t), 0));
  const rel = theta.map((t) => Math.atan2(Math.sin(t - centre), Math.cos(t - centre)));
  const widen = (lo, hi) => {
    const margin = Math.max(CONE_MARGIN, 0.5 * (hi - lo));
    return [lo - margin, hi + margin];
  };
  const [a0, a1] = widen(Math.min(...rel), Math.max(...rel));
  const [p0, p1] = widen(Math.min(...phi), Math.max(...phi));
  return {
    azimuth: [centre + a0, centre + a1],
    polar: [Math.max(0.01, p0), Math.min(Math.PI - 0.01, p1)],
  };
}

function dot(a, b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

function normalise(v) {
  const n = Math.hypot(...v) || 1;
  return v.map((x) => x / n);
}
