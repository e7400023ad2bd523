// cloudscape clouds in three.js, two ways:
//
// - mode=billboards (default): the tile's shaded metaballs as one InstancedMesh of
//   camera-facing quads, sorted back to front, each textured with the splat of the
//   server's sheet (/v1/splats.png) nearest its optical depth, animated between
//   keyframes by the documented rule (clients/js billboardsAt). The JS client fetches
//   a tile's first keyframe as billboards.bin and, animating, every later one as
//   billboards.delta.bin decoded on the keyframe it holds (CloudscapeClient.keyframe);
// - mode=volume: the density tile (density.u8) of the keyframes on either side of t as
//   two Data3DTextures, blended by the rule (render::keyframe::blend_density_at) and
//   ray-marched in a fragment shader with Beer–Lambert extinction and a shadow ray
//   toward the sun, as game engines draw volumetric clouds;
// - mode=ktx2: the same volume from density.ktx2 through three.js's KTX2Loader (one
//   keyframe).
//
// URL parameters: server (tile server origin; default this page's), world, layer, t,
// camera=X,Y,Z,YAW,PITCH,FOV (metres, z up; yaw clockwise from north, pitch above the
// horizon, horizontal FOV), sun=AZ,EL, quality, level, radius (metres of tiles around
// the camera), animate=1 (the clock runs at `rate` world seconds a second).
//
// World axes are z up (x east, y north); three.js is y up: (x, y, z) → (x, z, −y)
// relative to an origin under the camera (clients/js threeArrays, zUpToYUp).

import * as THREE from 'three';
import {
  CloudscapeClient,
  billboardsAt,
  decodeDensityU8,
  keyframeOf,
  threeArrays,
  tilesAround,
  zUpToYUp,
} from 'cloudscape-client';

const q = new URLSearchParams(location.search);
const num = (name, fallback) => (q.has(name) && Number.isFinite(Number(q.get(name))) ? Number(q.get(name)) : fallback);
const list = (name, n, fallback) => {
  const v = (q.get(name) || '').split(',').map(Number);
  return v.length === n && v.every(Number.isFinite) ? v : fallback;
};
const params = {
  server: q.get('server') || '',
  world: q.get('world') || 'default',
  layer: q.get('layer'),
  t: num('t', 43200),
  camera: list('camera', 6, [12800, -6000, 900, 0, 6, 75]),
  sun: q.has('sun') ? list('sun', 2, null) : null,
  quality: q.get('quality') || 'fast',
  level: num('level', 0),
  radius: num('radius', 0),
  mode: q.get('mode') || 'billboards',
  animate: q.get('animate') === '1',
  rate: num('rate', 4),
};
const info = document.getElementById('info');
const status = { ready: false, error: null, mode: params.mode, instances: 0, tiles: 0, keyframes: [], forms: [], requests: 0 };

const client = new CloudscapeClient(params.server, { quality: params.quality });
// The server's tone-map exposure (render::light::EXPOSURE, served in /v1/sky.json).
const exposure = (await (await fetch(client.url(`/v1/sky.json?t=${params.t}`))).json()).exposure ?? 1;
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.setSize(innerWidth, innerHeight);
document.body.append(renderer.domElement);
const scene = new THREE.Scene();
/** The ground seen past the clouds: a dark slate, so clouds stand out. */
scene.background = new THREE.Color(0.06, 0.08, 0.11);

// --- Camera: the cloudscape convention in three.js's frame. ----------------------
const [cx, cy, cz, yawDeg, pitchDeg, fovDeg] = params.camera;
/** World point (z up) that three.js's origin stands for: under the camera. */
const origin = [cx, cy, 0];
const rad = (d) => (d * Math.PI) / 180;
const aspect = innerWidth / innerHeight;
const vfov = (2 * Math.atan(Math.tan(rad(fovDeg) / 2) / aspect) * 180) / Math.PI;
const camera = new THREE.PerspectiveCamera(vfov, aspect, 5, 400000);
{
  const yaw = rad(yawDeg);
  const pitch = rad(pitchDeg);
  const forward = [Math.sin(yaw) * Math.cos(pitch), Math.cos(yaw) * Math.cos(pitch), Math.sin(pitch)];
  const right = [Math.cos(yaw), -Math.sin(yaw), 0];
  const up = [
    right[1] * forward[2] - right[2] * forward[1],
    right[2] * forward[0] - right[0] * forward[2],
    right[0] * forward[1] - right[1] * forward[0],
  ];
  camera.position.set(...zUpToYUp([0, 0, cz]));
  camera.up.set(...zUpToYUp(up));
  camera.lookAt(new THREE.Vector3(...zUpToYUp([forward[0], forward[1], cz + forward[2]])));
  camera.updateMatrixWorld();
}
const eye = [cx, cy, cz];

/** Canvas pixel (CSS px, top-left origin) of a z-up world point, or null behind the camera. */
function project(p) {
  const v = new THREE.Vector3(...zUpToYUp([p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]]));
  const view = v.clone().applyMatrix4(camera.matrixWorldInverse);
  if (view.z >= 0) return null;
  v.project(camera);
  return [((v.x + 1) / 2) * innerWidth, ((1 - v.y) / 2) * innerHeight];
}

// --- Billboards: one InstancedMesh, sorted back to front. ------------------------

const billboardMaterial = (splats, sheet) =>
  new THREE.ShaderMaterial({
    uniforms: {
      splats: { value: splats },
      // Columns, size (texels), sheet width and height.
      sheet: { value: new THREE.Vector4(sheet.columns, sheet.size, splats.image.width, splats.image.height) },
      // Splat count and tau_max: τ_k = tau_max ((k + 1) / count)².
      splatTable: { value: new THREE.Vector2(sheet.count, sheet.tau_max) },
      exposure: { value: exposure },
    },
    vertexShader: /* glsl */ `
      attribute vec3 instColour;  // linear RGB, pre-shaded (isotropic phase)
      attribute float instTau;    // centre optical depth at the drawn time
      uniform vec4 sheet;
      uniform vec2 splatTable;
      varying vec2 vCorner;
      varying vec2 vCell;
      varying float vPower;
      varying vec3 vColour;
      void main() {
        vec4 centre = modelViewMatrix * instanceMatrix * vec4(0.0, 0.0, 0.0, 1.0);
        float radius = length(instanceMatrix[0].xyz);
        vCorner = position.xy;
        centre.xy += position.xy * radius; // facing the camera
        gl_Position = projectionMatrix * centre;
        // The splat nearest τ, its opacity raised to τ / τ_k (the ball's own τ).
        float count = splatTable.x, tauMax = splatTable.y;
        float k = clamp(floor(sqrt(min(instTau, tauMax) / tauMax) * count - 0.5), 0.0, count - 1.0);
        float tauK = tauMax * ((k + 1.0) / count) * ((k + 1.0) / count);
        vPower = instTau / tauK;
        vCell = vec2(mod(k, sheet.x), floor(k / sheet.x)) * sheet.y;
        vColour = instColour;
      }`,
    fragmentShader: /* glsl */ `
      uniform sampler2D splats;
      uniform vec4 sheet;
      uniform float exposure;
      varying vec2 vCorner;
      varying vec2 vCell;
      varying float vPower;
      varying vec3 vColour;
      void main() {
        if (dot(vCorner, vCorner) >= 1.0) discard;
        float c = (sheet.y - 1.0) * 0.5; // texel centres span [-1, 1]
        vec2 texel = vCell + 0.5 + c + vCorner * c;
        float a = 1.0 - pow(max(1.0 - texture2D(splats, texel / sheet.zw).a, 1e-6), vPower);
        // The server's display mapping (render::light::tone_map): the exposure, then
        // 1 − e^(−x), gamma 1/2.2.
        vec3 colour = pow(1.0 - exp(-exposure * max(vColour, vec3(0.0))), vec3(1.0 / 2.2));
        gl_FragColor = vec4(colour, a);
      }`,
    transparent: true,
    depthWrite: false,
  });

async function billboards(world, tiles) {
  const sheet = await client.splats(params.quality);
  const splats = await new THREE.TextureLoader().loadAsync(client.url(`/v1/splats.png?quality=${params.quality}`));
  splats.flipY = false;
  splats.colorSpace = THREE.NoColorSpace;
  splats.generateMipmaps = false;
  splats.minFilter = THREE.LinearFilter;
  splats.premultiplyAlpha = false;
  const material = billboardMaterial(splats, sheet);
  const at = { quality: params.quality, sun: params.sun };
  let loaded = [];
  let mesh = null;
  let loadedFor = '';

  /**
   * The tiles' keyframes holding t: held by the client once fetched, the next ones
   * prefetched past each tile's prefetch point as deltas on them.
   */
  async function load(t) {
    const key = tiles.map((tile) => keyframeOf(world.layers.find((l) => l.name === tile.layer), tile.z, t).t0).join();
    if (key === loadedFor) return;
    loaded = await Promise.all(tiles.map((tile) => client.billboardTile(world, tile, { ...at, t })));
    loadedFor = key;
    status.keyframes = loaded.map((l) => [l.billboards.header.t0, l.billboards.header.t1]);
    status.forms = loaded.map((l) => l.billboards.header.form);
  }

  /** Rebuilds the instances at time t, sorted back to front from the eye. */
  function build(t) {
    const frames = loaded.map((l) => billboardsAt(l.billboards, t, sheet));
    const a = threeArrays(frames, { origin, eye });
    if (!mesh || mesh.count < a.count || mesh.instanceMatrix.count < a.count) {
      if (mesh) {
        scene.remove(mesh);
        mesh.dispose();
      }
      const geometry = new THREE.PlaneGeometry(2, 2);
      mesh = new THREE.InstancedMesh(geometry, material, Math.max(a.count, 1));
      mesh.frustumCulled = false;
      mesh.geometry.setAttribute('instColour', new THREE.InstancedBufferAttribute(new Float32Array(3 * mesh.count), 3));
      mesh.geometry.setAttribute('instTau', new THREE.InstancedBufferAttribute(new Float32Array(mesh.count), 1));
      scene.add(mesh);
    }
    const m = new THREE.Matrix4();
    for (let i = 0; i < a.count; i++) {
      const r = a.radii[i];
      m.makeScale(r, r, r).setPosition(a.positions[3 * i], a.positions[3 * i + 1], a.positions[3 * i + 2]);
      mesh.setMatrixAt(i, m);
    }
    mesh.count = a.count;
    mesh.geometry.getAttribute('instColour').array.set(a.colours);
    mesh.geometry.getAttribute('instTau').array.set(a.splatTaus);
    mesh.instanceMatrix.needsUpdate = true;
    mesh.geometry.getAttribute('instColour').needsUpdate = true;
    mesh.geometry.getAttribute('instTau').needsUpdate = true;
    status.instances = a.count;
  }

  await load(params.t);
  build(params.t);
  return async (t) => {
    await load(t);
    build(t);
  };
}

// --- Volume: density.u8 as a Data3DTexture, ray-marched. -------------------------

const volumeMaterial = (uniforms) =>
  new THREE.ShaderMaterial({
    glslVersion: THREE.GLSL3,
    uniforms,
    vertexShader: /* glsl */ `
      out vec3 vWorld;
      void main() {
        vec4 w = modelMatrix * vec4(position, 1.0);
        vWorld = w.xyz;
        gl_Position = projectionMatrix * viewMatrix * w;
      }`,
    fragmentShader: /* glsl */ `
      precision highp float;
      precision highp sampler3D;
      in vec3 vWorld;
      out vec4 colour;
      uniform sampler3D density0, density1;
      uniform vec3 boxMin, boxMax;   // the tile's volume, three.js frame (y up, z south)
      uniform float f;               // where t falls in the keyframe span
      uniform vec2 wind, shear;      // m/s and (m/s)/m, x east, y north
      uniform float layerBase;       // altitude of the layer's base (the wind's reference)
      uniform float since, until;    // t − t0 and t1 − t, seconds
      uniform vec3 sunDir, sunRgb, ambient;
      uniform float extinction, albedo, exposure;
      const int STEPS = 128;
      const int SHADOW_STEPS = 6;
      // The wind at a height, in three.js's frame (x east, z south).
      vec2 windAt(float y) { vec2 v = wind + shear * (y - layerBase); return vec2(v.x, -v.y); }
      float sampleGrid(sampler3D g, vec3 p) {
        vec3 size = boxMax - boxMin;
        // s east, t north (row 0 south), r up: density.u8's (depth, rows, cols).
        vec3 uvw = vec3((p.x - boxMin.x) / size.x, (boxMax.z - p.z) / size.z, (p.y - boxMin.y) / size.y);
        if (any(lessThan(uvw, vec3(0.0))) || any(greaterThan(uvw, vec3(1.0)))) return 0.0;
        return texture(g, uvw).r;
      }
      // render::keyframe::blend_density_at: (1 − f) D0(x − v (t − t0)) + f D1(x + v (t1 − t)).
      float densityAt(vec3 p) {
        vec2 v = windAt(p.y);
        float a = sampleGrid(density0, p - vec3(v.x, 0.0, v.y) * since);
        if (f <= 0.0) return a;
        float b = sampleGrid(density1, p + vec3(v.x, 0.0, v.y) * until);
        return mix(a, b, f);
      }
      vec2 hitBox(vec3 o, vec3 d) {
        vec3 inv = 1.0 / d;
        vec3 t0 = (boxMin - o) * inv, t1 = (boxMax - o) * inv;
        vec3 lo = min(t0, t1), hi = max(t0, t1);
        return vec2(max(max(lo.x, lo.y), lo.z), min(min(hi.x, hi.y), hi.z));
      }
      void main() {
        vec3 o = cameraPosition;
        vec3 d = normalize(vWorld - o);
        vec2 hit = hitBox(o, d);
        float t = max(hit.x, 0.0);
        if (hit.y <= t) discard;
        float ds = (hit.y - t) / float(STEPS);
        float T = 1.0;
        vec3 c = vec3(0.0);
        for (int i = 0; i < STEPS; i++) {
          vec3 p = o + d * (t + (float(i) + 0.5) * ds);
          float rho = densityAt(p);
          if (rho <= 0.002) continue;
          // Optical depth toward the sun (Beer–Lambert) through the layer.
          float tauSun = 0.0;
          vec2 toTop = hitBox(p, sunDir);
          float ls = max(toTop.y, 0.0) / float(SHADOW_STEPS);
          for (int j = 0; j < SHADOW_STEPS; j++) tauSun += extinction * densityAt(p + sunDir * (float(j) + 0.5) * ls) * ls;
          float sigma = extinction * rho;
          float a = 1.0 - exp(-sigma * ds);
          // The sun's share of the scattered light is sun_rgb / 4 (render::light::SUN_SCATTER).
          c += T * a * albedo * (0.25 * sunRgb * exp(-tauSun) + ambient);
          T *= 1.0 - a;
          if (T < 0.01) break;
        }
        float alpha = 1.0 - T;
        if (alpha <= 0.0) discard;
        vec3 rgb = pow(1.0 - exp(-exposure * c / alpha), vec3(1.0 / 2.2));
        colour = vec4(rgb * alpha, alpha);
      }`,
    side: THREE.BackSide,
    transparent: true,
    premultipliedAlpha: true,
    depthWrite: false,
  });

function densityTexture(bytes, depth) {
  const grid = decodeDensityU8(bytes, depth);
  const tex = new THREE.Data3DTexture(grid.data, 256, 256, depth);
  tex.format = THREE.RedFormat;
  tex.type = THREE.UnsignedByteType;
  tex.minFilter = THREE.LinearFilter;
  tex.magFilter = THREE.LinearFilter;
  tex.unpackAlignment = 1;
  tex.needsUpdate = true;
  return tex;
}

async function ktx2Texture(url) {
  const { KTX2Loader } = await import('three/addons/loaders/KTX2Loader.js');
  const loader = new KTX2Loader().setTranscoderPath('/three/examples/jsm/libs/basis/').detectSupport(renderer);
  const tex = await loader.loadAsync(url);
  tex.minFilter = THREE.LinearFilter;
  tex.magFilter = THREE.LinearFilter;
  status.ktx2 = { isData3DTexture: Boolean(tex.isData3DTexture), width: tex.image.width, height: tex.image.height, depth: tex.image.depth, format: tex.format, type: tex.type };
  loader.dispose();
  return tex;
}

async function volumes(world, tiles) {
  // The lighting of the tile (billboards.bin's header), so both modes shade alike.
  const lit = (await client.keyframe(world, tiles[0], { t: params.t, quality: params.quality, sun: params.sun })).header.lighting;
  const toThree = (v) => new THREE.Vector3(...zUpToYUp(v));
  for (const tile of tiles) {
    const layer = world.layers.find((l) => l.name === tile.layer);
    const k = keyframeOf(layer, tile.z, params.t, world.max_time);
    const at = { t: params.t, quality: params.quality };
    let d0;
    let d1;
    if (params.mode === 'ktx2') {
      d0 = await ktx2Texture(client.url(client.tilePath(world, tile, 'density.ktx2', at)));
      d1 = d0;
    } else {
      d0 = densityTexture(await client.tile(world, tile, 'density.u8', at), layer.depth);
      d1 = k.f > 0 ? densityTexture(await client.tile(world, tile, 'density.u8', { ...at, next: true }), layer.depth) : d0;
    }
    const f = params.mode === 'ktx2' ? 0 : k.f;
    status.keyframes.push([k.t0, k.t1]);
    const boxMin = new THREE.Vector3(tile.origin[0] - origin[0], layer.base, -(tile.origin[1] + tile.size - origin[1]));
    const boxMax = new THREE.Vector3(tile.origin[0] + tile.size - origin[0], layer.top, -(tile.origin[1] - origin[1]));
    const material = volumeMaterial({
      density0: { value: d0 },
      density1: { value: d1 },
      boxMin: { value: boxMin },
      boxMax: { value: boxMax },
      f: { value: f },
      wind: { value: new THREE.Vector2(...layer.wind) },
      shear: { value: new THREE.Vector2(...layer.shear) },
      layerBase: { value: layer.base },
      since: { value: f > 0 ? params.t - k.t0 : 0 },
      until: { value: k.t1 - params.t },
      sunDir: { value: toThree(lit.sunDirection).normalize() },
      sunRgb: { value: new THREE.Vector3(...lit.sunRgb) },
      ambient: { value: new THREE.Vector3(...lit.ambientRgb) },
      extinction: { value: lit.extinctionPerM },
      albedo: { value: lit.albedo },
      exposure: { value: exposure },
    });
    const size = new THREE.Vector3().subVectors(boxMax, boxMin);
    const box = new THREE.Mesh(new THREE.BoxGeometry(size.x, size.y, size.z), material);
    box.position.copy(boxMin).addScaledVector(size, 0.5);
    box.frustumCulled = false;
    scene.add(box);
  }
}

// --- Start. -------------------------------------------------------------------

async function start() {
  const world = await client.world(params.world);
  const layerName = params.layer || world.layers[0].name;
  const tiles = tilesAround(world, layerName, params.level, cx, cy, params.radius);
  status.tiles = tiles.length;
  let update = null;
  if (params.mode === 'billboards') update = await billboards(world, tiles);
  else await volumes(world, tiles);
  let t = params.t;
  const show = () => {
    renderer.render(scene, camera);
    status.t = t;
    status.requests = client.stats.requests;
    info.textContent = `${params.mode}: ${status.instances ? `${status.instances} billboards` : 'volume'}, ${tiles.length} tile(s), t = ${t.toFixed(1)} s`;
  };
  if (params.animate && update) {
    // The clock runs: every frame the billboards move by the rule; keyframes are
    // fetched when t enters them (prefetched past the middle of the span).
    let last = performance.now();
    let busy = false;
    renderer.setAnimationLoop(async (now) => {
      if (busy) return;
      busy = true;
      t += ((now - last) / 1000) * params.rate;
      last = now;
      await update(t);
      show();
      busy = false;
    });
  } else {
    // A still picture: drawn once (a ray-marched frame is costly without a GPU).
    show();
  }
  await new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r)));
  status.ready = true;
}

window.example = { status, project, params, client };
start().catch((e) => {
  status.error = String(e && e.stack ? e.stack : e);
  info.textContent = `error: ${e.message}`;
  console.error(e);
});
