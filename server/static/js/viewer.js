// The viewer: the trained model's .ply export (baked colour) drawn in the browser by Spark, a
// Gaussian-splat renderer for three.js, with orbit controls; the uploaded cameras drawn as
// frusta to jump to; and a button that renders the current pose on the server (the neural
// colour, exactly) to show beside the browser's drawing. With "live server view" (on by
// default where WebGL is a software renderer, too slow for the real splat count) the server
// renders the view as the camera moves (live.js) and the page shows those frames instead.

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { SparkRenderer, SplatMesh } from "@sparkjsdev/spark";
import { download, request } from "./api.js";
import { centreAndForward, coneRanges, isForwardFacing, openglCameraToWorld, orbitCentre, pinhole, placeThreeCamera, threeCameraToPinhole } from "./cameras.js";
import { renderUrl } from "./job.js";
import { LiveView } from "./live.js";
import { el, fmtBytes, toast } from "./ui.js";

const FRUSTUM_COLOURS = { train: 0x2563eb, test: 0xf97316 };
const MAX_WIDTH = 800;
const MAX_HEIGHT = 600;
/** The engine's rasterizer adds 0.3 px^2 to every projected covariance (3DGS's low-pass). */
const PRE_BLUR = 0.3;

const BACKGROUNDS = { white: 0xffffff, black: 0x000000, grey: 0x808080 };
/** Most splats drawn per frame on a software WebGL renderer (SwiftShader, llvmpipe), whose
 * cost per frame grows with the splat count (about 25-40 µs of CPU per splat here): Spark's
 * level-of-detail tree picks which (merged splats far away, the originals close up). Hardware
 * renderers draw every splat. A choice in the page; changing it takes a few frames to settle. */
const SOFTWARE_SPLATS = 5000;
const DETAIL_OPTIONS = [0, 50000, 20000, 10000, 5000, 2000];
/** The "every splat" budget: more than any model here, so every splat of at least a pixel is
 * drawn. */
const ALL_SPLATS = 20_000_000;
/** Largest live-view frame rendered at full size while the camera moves (504x378 and a bit). */
const LIVE_FULL_SIZE_PIXELS = 240_000;
/** Milliseconds after the last camera change before the view counts as still (snapshots). */
const SETTLE_MS = 250;

function isSoftwareRenderer(renderer) {
  const gl = renderer.getContext();
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  const name = info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  return { software: /swiftshader|llvmpipe|softpipe|software/i.test(String(name)), name: String(name) };
}

/** The vertex count of a binary .ply header (the number of Gaussians). */
function plyVertexCount(bytes) {
  const head = new TextDecoder().decode(bytes.subarray(0, Math.min(bytes.length, 4096)));
  const m = head.match(/element vertex (\d+)/);
  return m ? Number(m[1]) : null;
}

function backgroundFor(job) {
  const spec = job.spec || {};
  if (Array.isArray(spec.background)) return new THREE.Color(...spec.background);
  const preset = (job.progress && job.progress.preset) || spec.preset;
  if (preset === "dtu") return new THREE.Color(BACKGROUNDS.black);
  if (preset === "blender" || preset === "object") return new THREE.Color(BACKGROUNDS.white);
  return new THREE.Color(0x202020);
}

/** Line segments of a camera's frustum (pyramid to its image corners at `depth`), world frame. */
function frustum(camera, depth, colour) {
  const { width: w, height: h, fx, fy, cx, cy } = camera;
  // OpenGL camera axes: +x right, +y up, looking down -z.
  const corner = (u, v) => [((u - cx) / fx) * depth, (-(v - cy) / fy) * depth, -depth];
  const c = [corner(0, 0), corner(w, 0), corner(w, h), corner(0, h)];
  const o = [0, 0, 0];
  const tip = [0, (cy / fy) * depth * 1.35, -depth]; // a roof on the top edge: which way is up
  const segments = [o, c[0], o, c[1], o, c[2], o, c[3], c[0], c[1], c[1], c[2], c[2], c[3], c[3], c[0], c[0], tip, tip, c[1]];
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(segments.flat(), 3));
  const lines = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: colour }));
  lines.matrixAutoUpdate = false;
  lines.matrix.set(...openglCameraToWorld(camera).flat());
  lines.updateMatrixWorld(true);
  return lines;
}

export function mount(container, { jobId }) {
  let unmounted = false;
  const urls = [];
  const canvas = el("canvas#viewer-canvas", { tabindex: "0" });
  const fpsBox = el("div.overlay.fps#viewer-fps", {}, "");
  const loading = el("div.overlay.loading#viewer-loading", {}, "Loading the model…");
  const liveFrame = el("canvas#viewer-live-frame", { hidden: true });
  const wrap = el("div.canvas-wrap", {}, canvas, liveFrame, fpsBox, loading);
  const cameraList = el("div.camera-list#viewer-cameras");
  const renderButton = el("button#viewer-render", { type: "button", disabled: true }, "Render this view on the server");
  const spin = el("input#viewer-spin", { type: "checkbox" });
  const freeOrbit = el("input#viewer-free-orbit", { type: "checkbox" });
  const freeOrbitLabel = el(
    "label.check",
    { hidden: true, title: "A forward-facing capture shows nothing far outside the cone its cameras span; the orbit stays inside it unless this is ticked." },
    freeOrbit,
    " free orbit (leave the captured views)",
  );
  const liveToggle = el("input#viewer-live", { type: "checkbox" });
  const showFrusta = el("input#viewer-frusta", { type: "checkbox", checked: true });
  const detail = el(
    "select#viewer-detail",
    {},
    DETAIL_OPTIONS.map((n) => el("option", { value: String(n) }, n ? `at most ${n.toLocaleString()} splats` : "every splat")),
  );
  const background = el(
    "select#viewer-background",
    {},
    el("option", { value: "auto" }, "the model's"),
    ...Object.keys(BACKGROUNDS).map((name) => el("option", { value: name }, name)),
  );
  const info = el("dl.details#viewer-info");
  const pose = el("span#viewer-pose.muted", {}, "");
  const compare = el("section.card#viewer-compare", { hidden: true });
  container.append(
    el("p", {}, el("a", { href: `#/jobs/${jobId}` }, "← Job ", el("code", {}, jobId))),
    el(
      "section.card.viewer",
      {},
      el("div.viewer-main", {}, wrap),
      el(
        "div.viewer-side",
        {},
        el("p.muted", {}, "Drag to orbit, right-drag to pan, wheel to zoom. Click a frustum or a camera below to jump to it."),
        el("h3", {}, "Cameras"),
        cameraList,
        el("label.check", {}, showFrusta, " show camera frusta"),
        el("label.check", {}, spin, " auto-rotate"),
        freeOrbitLabel,
        el("label.check", { title: "The server renders the view as the camera moves (neural colour, exact); the browser draws nothing. On by default with software WebGL." }, liveToggle, " live server view"),
        el("label", {}, "Background ", background),
        el("label", { title: "Fewer splats keep software WebGL interactive (Spark's level of detail); 'Render this view on the server' is always exact." }, "Draw ", detail),
        el("p", {}, renderButton),
        el("p", {}, pose),
        info,
      ),
    ),
    compare,
  );

  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, alpha: false, powerPreference: "high-performance" });
  renderer.setPixelRatio(1); // software WebGL in CI: one pixel per canvas pixel
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(50, 1, 0.01, 1000);
  scene.add(camera);
  let dirty = true;
  const gpu = isSoftwareRenderer(renderer);
  detail.value = String(gpu.software ? SOFTWARE_SPLATS : 0);
  liveToggle.checked = gpu.software;
  let live = null; // the LiveView while the live server view is on
  let liveSentKey = null; // the pose last sent to it
  const spark = new SparkRenderer({
    renderer,
    preBlurAmount: PRE_BLUR,
    sortRadial: false,
    lodSplatCount: Number(detail.value) || ALL_SPLATS,
    onDirty: () => (dirty = true),
  });
  scene.add(spark);
  const frusta = new THREE.Group();
  scene.add(frusta);
  let controls = null;
  let mesh = null;

  let model = null;
  let job = null;
  let cameras = [];
  let orbit = { centre: [0, 0, 0], scale: 1, up: [0, 1, 0] };
  let cone = null; // a forward-facing capture's orbit ranges (coneRanges), null: free orbit
  let pinned = null; // the wire camera jumped to, until the user moves
  let size = { width: 640, height: 480 };
  let aspect = 4 / 3;
  const stats = { frames: 0, fps: 0, windowStart: performance.now(), windowFrames: 0, renderer: gpu.name, software: gpu.software, drawn: Number(detail.value) || "all", moving: false, stillFrames: 0, live: null, liveFps: 0, liveWindowShown: 0 };
  let lastChange = -Infinity;
  let interacting = false;
  let snapshotWaiters = [];
  let resolveReady;
  const ready = new Promise((resolve) => (resolveReady = resolve));

  function layout() {
    const available = Math.max(320, Math.min(MAX_WIDTH, wrap.clientWidth || MAX_WIDTH));
    let width = available;
    const maxHeight = Math.max(240, Math.min(MAX_HEIGHT, window.innerHeight - 160));
    let height = Math.round(width / aspect);
    if (height > maxHeight) {
      height = maxHeight;
      width = Math.round(height * aspect);
    }
    size = { width, height };
    renderer.setSize(width, height, true);
    liveFrame.style.width = `${width}px`;
    liveFrame.style.height = `${height}px`;
    camera.aspect = width / height;
    camera.updateProjectionMatrix();
    dirty = true;
  }

  function applyDetail() {
    const budget = Number(detail.value);
    stats.drawn = budget || "all";
    spark.lodSplatCount = budget || ALL_SPLATS;
    lastChange = performance.now();
    dirty = true;
  }

  function tick(now) {
    if (controls && spin.checked) {
      controls.update();
      dirty = true;
      lastChange = now;
    }
    stats.moving = spin.checked || interacting || now - lastChange < SETTLE_MS;
    if (live) {
      // The server draws: send the pose when it changed; the browser draws only for snapshots.
      const wire = currentCamera();
      // While moving, a large canvas is rendered at half size (a quarter of the pixels); the
      // still view is rendered at full size once the camera settles.
      const downscale = stats.moving && wire.width * wire.height > LIVE_FULL_SIZE_PIXELS ? 2 : 1;
      const key = `${JSON.stringify(wire)}/${downscale}`;
      if (key !== liveSentKey) {
        liveSentKey = key;
        live.send(wire, { downscale });
      }
      if (!snapshotWaiters.length) dirty = false;
    }
    if (dirty) {
      dirty = false;
      renderer.render(scene, camera);
      stats.frames += 1;
      stats.windowFrames += 1;
      stats.stillFrames = stats.moving ? 0 : stats.stillFrames + 1;
      // A snapshot is taken right after a draw of the still camera whose splat order is settled
      // (or, should sorting never settle, after a few draws).
      const settled = !spark.sorting && !spark.sortDirty;
      if (snapshotWaiters.length && stats.stillFrames > 0 && (settled || stats.stillFrames >= 4)) {
        const url = canvas.toDataURL("image/png");
        for (const resolve of snapshotWaiters) resolve(url);
        snapshotWaiters = [];
      }
    }
    if (snapshotWaiters.length && !dirty && !stats.moving && !spark.sorting) dirty = true;
    if (now - stats.windowStart >= 1000) {
      const elapsed = now - stats.windowStart;
      stats.fps = (stats.windowFrames * 1000) / elapsed;
      stats.windowStart = now;
      stats.windowFrames = 0;
      if (live) {
        const shown = live.stats.shown - stats.liveWindowShown;
        stats.liveWindowShown = live.stats.shown;
        stats.liveFps = (shown * 1000) / elapsed;
        fpsBox.textContent = shown > 0 ? `server ${stats.liveFps.toFixed(1)} fps · neural colour` : "server · still";
      } else {
        const drawn = stats.drawn === "all" ? "all splats" : `≤${stats.drawn.toLocaleString()} splats`;
        fpsBox.textContent = stats.fps > 0 ? `${stats.fps.toFixed(1)} fps · ${drawn}` : "still";
      }
    }
  }

  function jumpTo(index) {
    const wire = cameras[index];
    lastChange = performance.now();
    placeThreeCamera(camera, wire);
    camera.aspect = size.width / size.height;
    camera.updateProjectionMatrix();
    const { centre, forward } = centreAndForward(wire);
    const toCentre = orbit.centre.map((c, k) => c - centre[k]);
    let distance = toCentre[0] * forward[0] + toCentre[1] * forward[1] + toCentre[2] * forward[2];
    if (!(distance > 1e-6)) distance = orbit.scale;
    controls.target.set(...centre.map((c, k) => c + forward[k] * distance));
    pinned = wire;
    spin.checked = false;
    controls.autoRotate = false;
    // The camera's own frustum would frame the view's edges: hide it while looking through it.
    for (const f of frusta.children) f.visible = f.userData.index !== index;
    describePose();
    for (const button of cameraList.querySelectorAll("button")) button.classList.toggle("active", Number(button.dataset.index) === index);
    dirty = true;
  }

  /** Keep a forward-facing capture's orbit inside its cone (unless "free orbit" is ticked),
   * with a speed at which a drag across the whole canvas spans the cone; else the defaults. */
  function applyOrbitLimits() {
    const limited = cone !== null && !freeOrbit.checked;
    controls.minAzimuthAngle = limited ? cone.azimuth[0] : -Infinity;
    controls.maxAzimuthAngle = limited ? cone.azimuth[1] : Infinity;
    controls.minPolarAngle = limited ? cone.polar[0] : 0;
    controls.maxPolarAngle = limited ? cone.polar[1] : Math.PI;
    // OrbitControls turns by 2 pi rotateSpeed per canvas height dragged, in both directions.
    const across = (2 * Math.PI * size.width) / size.height;
    controls.rotateSpeed = limited
      ? Math.min(1, (cone.azimuth[1] - cone.azimuth[0]) / across, (cone.polar[1] - cone.polar[0]) / (2 * Math.PI))
      : 1;
    if (limited) spin.checked = controls.autoRotate = false; // auto-rotation would leave the cone
    spin.disabled = limited;
    controls.update();
    dirty = true;
  }

  function describePose() {
    pose.textContent = pinned
      ? `At camera #${pinned.index} (${pinned.split}): the server render uses it exactly (${pinned.width}×${pinned.height}).`
      : `Free camera: the server render uses this canvas's pose and size (${size.width}×${size.height}).`;
  }

  /** The wire camera the server renders: the pinned camera as given, else the canvas's. */
  function currentCamera() {
    return pinned ? pinhole(pinned) : threeCameraToPinhole(camera, size.width, size.height);
  }

  /** A PNG data URL of the canvas at the current pose, once the drawing has settled. */
  function snapshot() {
    dirty = true;
    return new Promise((resolve) => snapshotWaiters.push(resolve));
  }

  async function renderExact() {
    const wire = currentCamera();
    renderButton.disabled = true;
    const browser = await snapshot();
    const started = performance.now();
    compare.hidden = false;
    compare.replaceChildren(el("p.muted", {}, "Rendering on the server…"));
    try {
      const url = await renderUrl(jobId, wire, urls);
      if (unmounted) return null;
      const seconds = (performance.now() - started) / 1000;
      compare.replaceChildren(
        el("h3", {}, "This view: browser against server"),
        el(
          "div.pair",
          {},
          el("figure", {}, el("img#compare-viewer", { src: browser, alt: "browser drawing" }), el("figcaption", {}, `Browser (Spark, baked colour), ${size.width}×${size.height}`)),
          el("figure", {}, el("img#compare-server", { src: url, alt: "server render", dataset: { camera: JSON.stringify(wire) } }), el("figcaption", {}, `Server (neural colour), ${wire.width}×${wire.height}, ${seconds.toFixed(2)} s`)),
        ),
        el("details", {}, el("summary", {}, "Camera sent (POST /v1/models/{id}/render)"), el("pre", {}, JSON.stringify({ camera: wire, output: "png" }, null, 1))),
      );
      return wire;
    } catch (exc) {
      compare.replaceChildren(el("p.error-text", {}, `Server render failed: ${exc.message}`));
      return null;
    } finally {
      renderButton.disabled = false;
    }
  }

  /** Start or stop the live server view (the checkbox's state). */
  function setLive() {
    if (liveToggle.checked && !live && model) {
      live = new LiveView(jobId, {
        onFrame: (bitmap) => {
          if (!live) return bitmap.close();
          liveFrame.width = bitmap.width;
          liveFrame.height = bitmap.height;
          liveFrame.getContext("2d").drawImage(bitmap, 0, 0);
          bitmap.close();
          liveFrame.hidden = false;
        },
        onStatus: (status) => (liveFrame.dataset.status = status),
      }).start();
      stats.live = live.stats;
      stats.liveWindowShown = 0;
      liveSentKey = null;
    } else if (!liveToggle.checked && live) {
      live.stop();
      live = null;
      liveFrame.hidden = true;
      dirty = true;
    }
  }

  function setBackground() {
    scene.background = background.value === "auto" ? backgroundFor(job) : new THREE.Color(BACKGROUNDS[background.value]);
    dirty = true;
  }

  async function load() {
    try {
      job = await request(`/v1/jobs/${encodeURIComponent(jobId)}`);
      if (job.state !== "succeeded") {
        loading.textContent = `This job is ${job.state}: the viewer opens once it has succeeded.`;
        return;
      }
      model = await request(`/v1/models/${jobId}`);
    } catch (exc) {
      loading.textContent = `Cannot open the model: ${exc.message}`;
      return;
    }
    if (unmounted) return;
    cameras = model.cameras.map((c, index) => ({ ...c, index }));
    const training = cameras.filter((c) => c.split !== "test");
    const orbitCameras = training.length >= 2 ? training : cameras;
    orbit = orbitCentre(orbitCameras);
    aspect = cameras[0].width / cameras[0].height;
    camera.near = orbit.scale * 0.01;
    camera.far = orbit.scale * 100;
    camera.up.set(...orbit.up);
    layout();
    controls = new OrbitControls(camera, canvas);
    controls.target.set(...orbit.centre);
    controls.autoRotateSpeed = 4;
    if (isForwardFacing(orbitCameras)) {
      // Each training camera's heading reversed, in the controls' frame (up = +y): its
      // direction from any target on its own axis (where jumpTo puts the target), so every
      // training view lies inside the cone, and the orbit keeps to the directions the
      // capture looked from (the orbit centre of near-parallel cameras is poorly placed, and
      // directions from it are not).
      const toOrbitFrame = new THREE.Quaternion().setFromUnitVectors(camera.up.clone().normalize(), new THREE.Vector3(0, 1, 0));
      const offsets = orbitCameras.map((c) => {
        const back = new THREE.Vector3(...centreAndForward(c).forward).negate().applyQuaternion(toOrbitFrame);
        return [back.x, back.y, back.z];
      });
      cone = coneRanges(offsets);
      freeOrbitLabel.hidden = false;
    }
    freeOrbit.addEventListener("change", applyOrbitLimits);
    applyOrbitLimits();
    controls.addEventListener("start", () => {
      interacting = true;
      pinned = null;
      for (const f of frusta.children) f.visible = true;
      describePose();
      for (const b of cameraList.querySelectorAll("button.active")) b.classList.remove("active");
    });
    controls.addEventListener("change", () => {
      dirty = true;
      lastChange = performance.now();
    });
    controls.addEventListener("end", () => {
      interacting = false;
      lastChange = performance.now();
    });
    spin.addEventListener("change", () => {
      controls.autoRotate = spin.checked;
      lastChange = performance.now();
      dirty = true;
      if (spin.checked) {
        pinned = null;
        for (const f of frusta.children) f.visible = true;
        describePose();
      }
    });
    setBackground();
    for (const wire of cameras) frusta.add(frustum(wire, orbit.scale * 0.12, FRUSTUM_COLOURS[wire.split] ?? 0x888888));
    for (const [i, f] of frusta.children.entries()) f.userData.index = i;
    cameraList.replaceChildren(
      ...cameras.map((wire) =>
        el(
          `button.small.camera.${wire.split}`,
          { type: "button", dataset: { index: String(wire.index), split: wire.split }, onclick: () => jumpTo(wire.index) },
          `#${wire.index} ${wire.split}`,
        ),
      ),
    );
    jumpTo(cameras.findIndex((c) => c.split !== "test"));
    renderer.setAnimationLoop(tick);
    setLive(); // the server's frames need no download: they show while the .ply loads

    const started = performance.now();
    let bytes;
    try {
      bytes = await download(`/v1/models/${jobId}/export/ply`, (loaded, total) => {
        loading.textContent = `Loading the model… ${fmtBytes(loaded)}${total ? ` of ${fmtBytes(total)}` : ""}`;
      });
    } catch (exc) {
      loading.textContent = `Cannot download the .ply: ${exc.message}`;
      return;
    }
    if (unmounted) return;
    loading.textContent = "Preparing the splats…";
    // Every splat as exported for the still view; on a software renderer also a
    // level-of-detail copy (Spark's LoD tree) drawn while the camera moves.
    // With Spark's level-of-detail tree, so that a software renderer can draw fewer splats.
    mesh = new SplatMesh({ fileBytes: bytes, fileName: "model.ply", lod: true });
    scene.add(mesh);
    await mesh.initialized;
    if (unmounted) return;
    const seconds = (performance.now() - started) / 1000;
    loading.hidden = true;
    renderButton.disabled = false;
    const n = plyVertexCount(bytes) ?? model.n_gaussians;
    info.replaceChildren(
      ...[
        ["Gaussians", n.toLocaleString()],
        [".ply", `${fmtBytes(bytes.length)}, loaded in ${seconds.toFixed(1)} s`],
        ["Trained", `${model.iterations} iterations`],
        ["Held-out PSNR", model.metrics.psnr != null ? `${model.metrics.psnr.toFixed(2)} dB` : "–"],
        ["WebGL", `${gpu.software ? "software" : "hardware"}: ${gpu.name}`],
      ].flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]),
    );
    canvas.dataset.ready = "1";
    dirty = true;
    resolveReady(true);
  }

  // A click (not a drag) on a frustum jumps to its camera.
  const raycaster = new THREE.Raycaster();
  let down = null;
  canvas.addEventListener("pointerdown", (e) => (down = [e.clientX, e.clientY]));
  canvas.addEventListener("pointerup", (e) => {
    if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 3 || !frusta.visible) return;
    const rect = canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((e.clientX - rect.left) / rect.width) * 2 - 1, -((e.clientY - rect.top) / rect.height) * 2 + 1);
    raycaster.params.Line.threshold = orbit.scale * 0.01;
    raycaster.setFromCamera(ndc, camera);
    const hit = raycaster.intersectObjects(frusta.children, false)[0];
    if (hit) jumpTo(hit.object.userData.index);
  });
  showFrusta.addEventListener("change", () => {
    frusta.visible = showFrusta.checked;
    dirty = true;
  });
  background.addEventListener("change", setBackground);
  detail.addEventListener("change", applyDetail);
  liveToggle.addEventListener("change", setLive);

  renderButton.addEventListener("click", renderExact);
  const onResize = () => {
    if (controls) layout();
  };
  window.addEventListener("resize", onResize);
  load().catch((exc) => {
    loading.textContent = `Viewer failed: ${exc.message}`;
    toast(`Viewer: ${exc.message}`);
  });

  return {
    name: "viewer",
    ready,
    stats,
    camera,
    canvas,
    renderer,
    spark,
    get controls() {
      return controls;
    },
    get mesh() {
      return mesh;
    },
    get pinned() {
      return pinned;
    },
    get size() {
      return size;
    },
    get cameras() {
      return cameras;
    },
    get cone() {
      return cone;
    },
    get live() {
      return live;
    },
    jumpTo,
    currentCamera,
    renderExact,
    snapshot,
    unmount() {
      unmounted = true;
      window.removeEventListener("resize", onResize);
      renderer.setAnimationLoop(null);
      if (live) live.stop();
      if (controls) controls.dispose();
      if (mesh) mesh.dispose();

      renderer.dispose();
      for (const url of urls) URL.revokeObjectURL(url);
    },
  };
}
