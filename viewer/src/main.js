// abcgs offline splat viewer: Spark (Gaussian splatting for three.js) in one IIFE bundle that works
// from file:// with no network. The page provides its data inline:
//   <script type="application/json" id="abcgs-viewer-data">{"experiments": [...]}</script>
//   <script type="application/octet-stream" id="...">base64 of a .spz file</script>
// and a container <div id="abcgs-viewer">. Each experiment names one splat element per layer
// ("original", "stylized", "labels"), its training cameras (three.js convention: position, quaternion
// xyzw, vertical fov in degrees, aspect), an orbit target and a camera path (`path`: cameras of the
// video path, `path_kind`: "orbit" around an object-centred capture or "spiral" through a forward-facing
// one; the same path as the turntable video). All splats share one world frame (the COLMAP frame of the
// scene; no axis conversion).
// Test hooks: window.abcgsViewer = {ready, setExperiment, setMode, setCamera, setPathFrame, play, orbit,
// settle, state}.
import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { SparkRenderer, SplatFileType, SplatMesh, defines } from "@sparkjsdev/spark";

const LAYERS = ["original", "stylized", "labels"];

function b64ToBytes(b64) {
  const bin = atob(b64.replace(/\s+/g, ""));
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

function el(tag, attrs = {}, text = "") {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text) e.textContent = text;
  return e;
}

class Viewer {
  constructor(root, data) {
    this.root = root;
    this.data = data;
    this.exp = null;
    this.meshes = {};
    this.mode = "stylized";
    this.cameraIndex = 0;
    this.frames = 0;
    this._build();
  }

  _build() {
    const bar = el("div", { class: "abcgs-bar" });
    this.select = el("select", { id: "abcgs-experiment", "aria-label": "experiment" });
    this.data.experiments.forEach((e, i) => this.select.appendChild(el("option", { value: String(i) }, e.name)));
    this.select.addEventListener("change", () => this.setExperiment(Number(this.select.value)));
    bar.appendChild(this.select);
    this.modeButtons = {};
    for (const m of LAYERS) {
      const b = el("button", { type: "button", "data-mode": m }, m);
      b.addEventListener("click", () => this.setMode(m));
      this.modeButtons[m] = b;
      bar.appendChild(b);
    }
    const prev = el("button", { type: "button", id: "abcgs-prev" }, "◀");
    const next = el("button", { type: "button", id: "abcgs-next" }, "▶");
    this.camLabel = el("span", { id: "abcgs-camera" });
    prev.addEventListener("click", () => this.setCamera(this.cameraIndex - 1));
    next.addEventListener("click", () => this.setCamera(this.cameraIndex + 1));
    bar.append(prev, this.camLabel, next);
    this.playButton = el("button", { type: "button", id: "abcgs-play" }, "▷ path");
    this.playButton.addEventListener("click", () => this.play(!this._playing));
    bar.appendChild(this.playButton);
    this.note = el("div", { class: "abcgs-note", id: "abcgs-note" });
    this.error = el("div", { class: "abcgs-error", id: "abcgs-error", role: "alert" });
    this.error.style.display = "none";
    this.canvasHolder = el("div", { class: "abcgs-canvas" });
    this.root.append(bar, this.canvasHolder, this.note, this.error);

    this.renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true, alpha: true });
    this.renderer.setPixelRatio(1);
    this.renderer.setClearColor(0xffffff, 1);
    this.canvas = this.renderer.domElement;
    this.canvas.id = "abcgs-canvas";
    this.canvasHolder.appendChild(this.canvas);
    this.scene = new THREE.Scene();
    // Match the rasterizer the scenes were trained with (abcgs.render, as INRIA 3DGS): z-depth sort, 0.3 px²
    // added to the 2-D covariance, a 3.33 σ footprint, no level-of-detail merging.
    this.spark = new SparkRenderer({
      renderer: this.renderer,
      sortRadial: false,
      preBlurAmount: 0.3,
      maxStdDev: 3.33,
      maxPixelRadius: 2048,
      enableLod: false,
    });
    this.scene.add(this.spark);
    this.camera = new THREE.PerspectiveCamera(50, 4 / 3, 0.01, 1000);
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.enableDamping = false;
    this.renderer.setAnimationLoop((t) => {
      if (this._playing && this.exp?.path?.length) {
        // 24 path frames per second, as the turntable video
        const frame = Math.floor(((t - this._playStart) / 1000) * 24) % this.exp.path.length;
        if (frame !== this.state.pathFrame) this.setPathFrame(frame);
      }
      this.controls.update();
      this.renderer.render(this.scene, this.camera);
      this.frames++;
    });
  }

  showError(msg) {
    this.error.textContent = msg;
    this.error.style.display = "block";
    this.state.error = msg;
  }

  async setExperiment(i) {
    const exp = this.data.experiments[i];
    if (!exp) throw new Error(`no experiment ${i}`);
    for (const m of Object.values(this.meshes)) {
      this.scene.remove(m);
      m.dispose?.();
    }
    this.meshes = {};
    this.exp = exp;
    this.select.value = String(i);
    // An object scene shows on its background colour, or over the page (transparent); a frame-filling one on white.
    const bg = exp.background;
    if (bg && bg.transparent) this.renderer.setClearColor(0x000000, 0);
    else if (bg) this.renderer.setClearColor(new THREE.Color().setRGB(bg.color[0], bg.color[1], bg.color[2], THREE.SRGBColorSpace), 1);
    else this.renderer.setClearColor(0xffffff, 1);
    const cam0 = exp.cameras[0];
    const width = Math.min(this.root.clientWidth || 800, exp.max_width || 960);
    this.renderer.setSize(width, Math.round(width / cam0.aspect), true);
    const loads = [];
    for (const layer of LAYERS) {
      const id = exp.layers?.[layer];
      this.modeButtons[layer].disabled = !id;
      if (!id) continue;
      const node = document.getElementById(id);
      if (!node) {
        this.showError(`splat data for layer '${layer}' of '${exp.name}' is missing from the page (element #${id})`);
        continue;
      }
      let bytes;
      try {
        bytes = b64ToBytes(node.textContent);
      } catch (err) {
        this.showError(`splat data for layer '${layer}' of '${exp.name}' is not valid base64: ${err.message}`);
        continue;
      }
      // Spark packs colours into [rgbMin, rgbMax] (default [0, 1]); stylized scenes carry over-saturated
      // colours that only blend back into range, so keep the whole range .spz can hold ([-0.44, 1.44]).
      const mesh = new SplatMesh({
        fileBytes: bytes,
        fileType: SplatFileType.SPZ,
        fileName: `${layer}.spz`,
        splatEncoding: { ...defines.DEFAULT_SPLAT_ENCODING, rgbMin: -0.5, rgbMax: 1.5 },
      });
      mesh.visible = false;
      this.meshes[layer] = mesh;
      this.scene.add(mesh);
      loads.push(
        mesh.initialized.catch((err) => {
          this.showError(`could not decode the '${layer}' splat of '${exp.name}': ${err?.message || err}`);
          this.scene.remove(mesh);
          delete this.meshes[layer];
        }),
      );
    }
    const shown = exp.n_gaussians_page === exp.n_gaussians_full
      ? `all ${exp.n_gaussians_full.toLocaleString()} Gaussians`
      : `${exp.n_gaussians_page.toLocaleString()} of ${exp.n_gaussians_full.toLocaleString()} Gaussians ` +
        "(the most visible, subsampled for the page)";
    this.note.textContent =
      `${exp.name}: showing ${shown}; the full scene is ${exp.full_artifact}. Drag to orbit, right-drag to ` +
      "pan, wheel to zoom; ◀ ▶ step through the training cameras; ▷ plays the " +
      `${exp.path_kind || "video"} path.`;
    await Promise.all(loads);
    this.setMode(this.meshes[this.mode] ? this.mode : Object.keys(this.meshes)[0] || this.mode);
    this.play(false);
    this.playButton.disabled = !exp.path?.length;
    this.playButton.title = exp.path?.length ? `play the ${exp.path_kind} path (${exp.path.length} frames)` : "";
    this.setCamera(0);
    this.state.experiment = exp.name;
  }

  setMode(mode) {
    if (!LAYERS.includes(mode)) throw new Error(`unknown mode ${mode}`);
    this.mode = mode;
    for (const [m, mesh] of Object.entries(this.meshes)) mesh.visible = m === mode;
    for (const [m, b] of Object.entries(this.modeButtons)) b.classList.toggle("active", m === mode);
    this.state.mode = mode;
  }

  _applyCamera(c) {
    this.camera.fov = c.fov_y_deg;
    this.camera.aspect = c.aspect;
    this.camera.near = c.near || 0.01;
    this.camera.far = c.far || 1000;
    this.camera.updateProjectionMatrix();
    this.camera.position.fromArray(c.position);
    this.camera.quaternion.fromArray(c.quaternion);
    this.camera.up.set(0, 1, 0).applyQuaternion(this.camera.quaternion);
    const forward = new THREE.Vector3(0, 0, -1).applyQuaternion(this.camera.quaternion);
    const dist = this.camera.position.distanceTo(new THREE.Vector3().fromArray(this.exp.target));
    this.controls.target.copy(this.camera.position).addScaledVector(forward, dist);
    this.controls.update();
  }

  setCamera(i) {
    const cams = this.exp.cameras;
    const n = cams.length;
    this.cameraIndex = ((i % n) + n) % n;
    const c = cams[this.cameraIndex];
    this._applyCamera(c);
    this.camLabel.textContent = ` camera ${this.cameraIndex + 1}/${n} (${c.name}) `;
    this.state.camera = this.cameraIndex;
    this.state.pathFrame = null;
  }

  // Show frame i of the experiment's camera path (the turntable video's cameras).
  setPathFrame(i) {
    const path = this.exp.path || [];
    if (!path.length) throw new Error(`experiment ${this.exp.name} has no camera path`);
    const n = path.length;
    const k = ((i % n) + n) % n;
    this._applyCamera(path[k]);
    this.camLabel.textContent = ` ${this.exp.path_kind} path ${k + 1}/${n} `;
    this.state.pathFrame = k;
  }

  // Start (true) or stop (false) playing the camera path.
  play(on) {
    this._playing = Boolean(on) && Boolean(this.exp?.path?.length);
    this._playStart = performance.now();
    this.playButton.textContent = this._playing ? "❚❚ path" : "▷ path";
    this.playButton.classList.toggle("active", this._playing);
    this.state.playing = this._playing;
  }

  // Rotate the view about the orbit target by `radians` (azimuth), as a drag would.
  orbit(radians) {
    const offset = this.camera.position.clone().sub(this.controls.target);
    offset.applyAxisAngle(this.camera.up, radians);
    this.camera.position.copy(this.controls.target).add(offset);
    this.camera.lookAt(this.controls.target);
    this.controls.update();
  }

  // A cheap fingerprint of the drawn picture (the canvas scaled down to 32×24).
  _fingerprint() {
    if (!this._probe) {
      this._probe = document.createElement("canvas");
      this._probe.width = 32;
      this._probe.height = 24;
    }
    const ctx = this._probe.getContext("2d", { willReadFrequently: true });
    ctx.drawImage(this.canvas, 0, 0, 32, 24);
    const px = ctx.getImageData(0, 0, 32, 24).data;
    let h = 0;
    for (let i = 0; i < px.length; i++) h = (h * 31 + px[i]) | 0;
    return h;
  }

  // Resolve after `n` more frames have been drawn and the picture has stopped changing (Spark decodes and
  // sorts in a worker, so a change of mode or view shows up some frames later), or after `timeoutMs`.
  settle(n = 20, timeoutMs = 60000) {
    const goal = this.frames + n;
    const t0 = performance.now();
    let last = null;
    let same = 0;
    return new Promise((resolve) => {
      const tick = () => {
        if (this.frames >= goal) {
          const f = this._fingerprint();
          same = f === last ? same + 1 : 0;
          last = f;
          if (same >= 3 || performance.now() - t0 > timeoutMs) return resolve(this.frames);
        }
        requestAnimationFrame(tick);
      };
      tick();
    });
  }
}

function boot() {
  const root = document.getElementById("abcgs-viewer");
  const api = { state: { error: null } };
  window.abcgsViewer = api;
  if (!root) return;
  const fail = (msg) => {
    api.state.error = msg;
    const e = el("div", { class: "abcgs-error", id: "abcgs-error", role: "alert" }, msg);
    root.appendChild(e);
  };
  const node = document.getElementById("abcgs-viewer-data");
  if (!node) return fail("viewer data (#abcgs-viewer-data) is missing from the page");
  let data;
  try {
    data = JSON.parse(node.textContent);
  } catch (err) {
    return fail(`viewer data is not valid JSON: ${err.message}`);
  }
  if (!data.experiments?.length) return fail("the page lists no experiments to view");
  let viewer;
  try {
    viewer = new Viewer(root, data);
  } catch (err) {
    return fail(`WebGL viewer could not start: ${err.message}`);
  }
  viewer.state = api.state;
  Object.assign(api, {
    viewer,
    setExperiment: (i) => viewer.setExperiment(i),
    setMode: (m) => viewer.setMode(m),
    setCamera: (i) => viewer.setCamera(i),
    setPathFrame: (i) => viewer.setPathFrame(i),
    play: (on) => viewer.play(on),
    orbit: (r) => viewer.orbit(r),
    settle: (n) => viewer.settle(n),
  });
  api.ready = viewer.setExperiment(0).then(() => viewer.settle(30)).catch((err) => viewer.showError(String(err)));
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", boot);
else boot();
