// cloudscape clouds in three.js, two ways:
//
// - mode=billboards (default): what `cloudscape render` draws, in three.js. The tiles
//   the server's renderer plans for the camera (the JS client's planTiles), their
//   shaded metaballs as one InstancedMesh of camera-facing quads sorted back to front,
//   animated between keyframes by the documented rule (clients/js billboardsAt), over
//   the server's sky and the ground shadowed by maps derived from the billboards, each
//   billboard lit through the other layers above it by those maps (clients/js
//   lightBeneathLayers); the shading is the client's GLSL of the server's light. The JS client fetches a tile's
//   first keyframe as billboards.bin and, animating, every later one as
//   billboards.delta.bin decoded on the keyframe it holds (CloudscapeClient.keyframe);
// - mode=volume: the density tile (density.u8) of the keyframes on either side of t as
//   two Data3DTextures, blended by the rule (render::keyframe::blend_density_at) and
//   ray-marched in a fragment shader with Beer–Lambert extinction and a shadow ray
//   toward the sun, as game engines draw volumetric clouds;
// - mode=ktx2: the same volume from density.ktx2 through three.js's KTX2Loader (one
//   keyframe).
//
// URL parameters: server (tile server origin; default this page's), world, layer (the
// one layer drawn; billboards: default all), t, camera=X,Y,Z,YAW,PITCH,FOV (metres, z
// up; yaw clockwise from north, pitch above the horizon, horizontal FOV), sun=AZ,EL,
// quality, animate=1 (the clock runs at `rate` world seconds a second); the volume
// modes: level and radius (metres of tiles around the camera).
//
// World axes are z up (x east, y north); three.js is y up: (x, y, z) → (x, z, −y)
// relative to an origin under the camera (clients/js threeArrays, zUpToYUp).

import * as THREE from 'three';
import {
  CloudscapeClient,
  GLSL,
  MAX_DETAIL_OCTAVES,
  MIN_WAVELENGTH_PIXELS,
  SHADOW_FADE_START,
  ShadowDerivation,
  TILE_COLUMNS,
  VIEW_DISTANCE,
  billboardsAt,
  cameraBasis,
  decodeDensityU8,
  fraction,
  keyframeOf,
  lightBeneathLayers,
  planTiles,
  shadowShift,
  skyUniforms,
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
/** Behind the ray-marched volume: a dark slate, so clouds stand out. */
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

// --- Billboards: what `cloudscape render` draws. ---------------------------------
//
// The tiles `cloudscape render` plans for the camera (planTiles: every layer, or only
// `layer=`), their billboards at t by the animation rule as one InstancedMesh of
// camera-facing quads sorted back to front, the splat profile evaluated per pixel;
// over the server's sky (/v1/sky.json) and the ground shadowed by the maps derived from
// the billboards (ShadowDerivation); in linear radiance into a half-float target, the
// clouds' accumulated opacity eroded by the detail noise, and mapped for display once.
// The shading is the JS client's GLSL (the server's light, as the viewer draws it).

/** Most tiles a view may plan (render::scene::MAX_RENDER_TILES): `cloudscape render` refuses more. */
const MAX_TILES = 24;
/** Detail erosion strength (render::Quality::light, the same in every preset). */
const DETAIL_EROSION = 0.3;
/** A ball this many radii from the eye is fog around it, closer than half a radius along the view axis it is beside it (render::composite). */
const AROUND_EYE_RADII = 2.0;
const NEAR_CLIP_RADII = 0.5;

/** Uniforms of GLSL.atmosphere, GLSL.ground and GLSL.tone for sky.json (skyUniforms). */
function skyUniformsThree(sky) {
  const { table, values: v } = skyUniforms(sky);
  const texture = new THREE.DataTexture(table.data, table.columns, table.rows, THREE.RGBAFormat, THREE.FloatType);
  texture.minFilter = THREE.LinearFilter;
  texture.magFilter = THREE.LinearFilter;
  texture.needsUpdate = true;
  const v3 = (a) => new THREE.Vector3(...a);
  return {
    skyTable: { value: texture },
    skySize: { value: new THREE.Vector2(...v.skySize) },
    sunDir: { value: v3(v.sunDir) },
    night: { value: v3(v.night) },
    betaR: { value: v3(v.betaR) },
    mie: { value: new THREE.Vector4(...v.mie) },
    air: { value: new THREE.Vector4(...v.air) },
    sunT: { value: new Float32Array(v.sunT) },
    multi: { value: new Float32Array(v.multi) },
    sunGround: { value: v3(v.sunGround) },
    above: { value: v3(v.above) },
    groundAlbedo: { value: v3(v.groundAlbedo) },
    exposure: { value: v.exposure },
    toneOut: { value: false },
  };
}

/** The camera's unit vectors (z up) and the half-angle tangents, as uniforms. */
const { forward: camForward, right: camRight, up: camUp } = cameraBasis({ yaw: yawDeg, pitch: pitchDeg });
const viewUniforms = () => ({
  forward: { value: new THREE.Vector3(...camForward) },
  right: { value: new THREE.Vector3(...camRight) },
  up: { value: new THREE.Vector3(...camUp) },
  tanHalf: { value: new THREE.Vector2(Math.tan(rad(fovDeg) / 2), Math.tan(rad(fovDeg) / 2) / aspect) },
  eyeZ: { value: cz },
});

/** A full-screen quad drawn with `material` (its vertex shader places it), outside any frustum test. */
function screenQuad(material) {
  const mesh = new THREE.Mesh(new THREE.PlaneGeometry(2, 2), material);
  mesh.frustumCulled = false;
  return mesh;
}
const SCREEN_VERTEX = /* glsl */ `
  out vec2 ndc;
  void main() { ndc = position.xy; gl_Position = vec4(position.xy, 0.0, 1.0); }`;

// Sky and ground (scene::background): the ground's sun transmittance the product of
// the tiles' shadow maps at the ground point (1 outside them), turned into `far`, the
// mean shadow of the tiles, over the last 30 % of the view distance.
const backgroundMaterial = (uniforms) =>
  new THREE.ShaderMaterial({
    glslVersion: THREE.GLSL3,
    uniforms,
    vertexShader: SCREEN_VERTEX,
    fragmentShader: /* glsl */ `
      precision highp float;
      precision highp sampler2DArray;
      in vec2 ndc;
      uniform vec3 forward, right, up;
      uniform vec2 tanHalf;
      uniform float eyeZ;
      uniform vec3 sunRgb;
      uniform vec2 disc; // angular radius, gain
      uniform sampler2DArray shadowMaps; // per tile: R transmittance at t0, G at t1
      uniform vec4 shadowRects[${MAX_TILES}]; // x0, y0 relative to the eye, side, f
      uniform int shadowCount;
      uniform bool shadows;
      uniform float far, viewDistance;
      out vec4 colour;
      ${GLSL.tone}
      ${GLSL.atmosphere}
      ${GLSL.ground}
      void main() {
        vec3 d = normalize(forward + ndc.x * tanHalf.x * right + ndc.y * tanHalf.y * up);
        vec3 c;
        if (d.z >= 0.0 || eyeZ <= 0.0) {
          c = skyRadiance(d);
          float angle = acos(clamp(dot(d, sunDir), -1.0, 1.0));
          c += (1.0 - smoothstep(0.75 * disc.x, 1.25 * disc.x, angle)) * disc.y * sunRgb;
        } else {
          vec3 ray = d * (eyeZ / -d.z);
          float t = 1.0;
          if (shadows) {
            float fade = smoothstep(${SHADOW_FADE_START.toFixed(2)} * viewDistance, viewDistance, length(ray.xy));
            float near = 1.0;
            for (int i = 0; i < ${MAX_TILES}; i++) {
              if (i >= shadowCount) break;
              vec4 r = shadowRects[i];
              vec2 uv = (ray.xy - r.xy) / r.z;
              if (any(lessThanEqual(uv, vec2(0.0))) || any(greaterThanEqual(uv, vec2(1.0)))) continue;
              vec4 s = texture(shadowMaps, vec3(uv, float(i)));
              near *= mix(s.r, s.g, r.w);
            }
            t = near + fade * (far - near);
          }
          c = ground(ray, eyeZ, t);
        }
        colour = vec4(c, 1.0);
      }`,
    depthTest: false,
    depthWrite: false,
  });

// Billboards (render::composite): opacity 1 − exp(−τ P(q)) per pixel, colour the
// pre-shaded colour plus the octaves' phase correction for the direction to the
// centre, through the air between; a ball within AROUND_EYE_RADII of the eye covers
// the screen with the part of its chord in front of the eye along each pixel's ray.
// Writes (colour · α, α) and, for the erosion pass, (n · α, α, 0, α).
const billboardMaterial = (uniforms) =>
  new THREE.ShaderMaterial({
    glslVersion: THREE.GLSL3,
    uniforms,
    vertexShader: /* glsl */ `
      in vec3 instColour; // pre-shaded colour at t (isotropic phase, linear)
      in vec2 instTaus;   // centre optical depth, sun optical depth, at t
      uniform vec3 forward, right, up, sunRgb;
      uniform float eyeZ, pixelAngle, albedo;
      uniform vec3 phase;
      uniform vec4 octaves;
      out vec2 corner;
      out vec3 radiance;
      out vec3 rel;
      flat out float radius;
      flat out float tau;
      flat out int detailOctaves;
      flat out vec4 aroundEye;
      flat out vec4 fogColourTauSun;
      ${GLSL.atmosphere}
      ${GLSL.octaves}
      void main() {
        corner = position.xy;
        vec3 centre = (instanceMatrix * vec4(0.0, 0.0, 0.0, 1.0)).xyz; // y up, from the origin under the eye
        radius = length(instanceMatrix[0].xyz);
        tau = instTaus.x;
        vec3 c = vec3(centre.x, -centre.z, centre.y - eyeZ); // z up, from the eye
        float dist = length(c);
        aroundEye = vec4(0.0);
        if (!(tau > 0.0) || (dist >= ${AROUND_EYE_RADII.toFixed(1)} * radius && dot(c, forward) < ${NEAR_CLIP_RADII.toFixed(1)} * radius)) {
          gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
          return;
        }
        if (dist < ${AROUND_EYE_RADII.toFixed(1)} * radius) {
          aroundEye = vec4(c / radius, 1.0);
          fogColourTauSun = vec4(instColour, instTaus.y);
          detailOctaves = 0;
          gl_Position = vec4(corner, 0.0, 1.0);
          return;
        }
        vec3 p = c + (corner.x * right + corner.y * up) * radius;
        rel = p;
        float mpp = dot(c, forward) * pixelAngle;
        float wl = radius;
        detailOctaves = 0;
        while (detailOctaves < ${MAX_DETAIL_OCTAVES} && wl >= ${MIN_WAVELENGTH_PIXELS.toFixed(1)} * mpp) {
          detailOctaves++;
          wl *= 0.5;
        }
        gl_Position = projectionMatrix * viewMatrix * vec4(p.x, p.z + eyeZ, -p.y, 1.0);
        radiance = max(instColour + phaseCorrection(instTaus.y, normalize(c)), vec3(0.0));
        vec3 T, L;
        aerial(c, eyeZ, c.z + eyeZ, 1.0, T, L);
        radiance = radiance * T + L;
      }`,
    fragmentShader: /* glsl */ `
      precision highp float;
      precision highp int;
      in vec2 corner;
      in vec3 radiance;
      in vec3 rel;
      flat in float radius;
      flat in float tau;
      flat in int detailOctaves;
      flat in vec4 aroundEye;
      flat in vec4 fogColourTauSun;
      uniform vec3 forward, right, up, sunRgb, sunDir, eyeMod;
      uniform vec2 tanHalf, viewport;
      uniform float albedo;
      uniform vec3 phase;
      uniform vec4 octaves;
      layout(location = 0) out vec4 colour;
      layout(location = 1) out vec4 detailOut;
      ${GLSL.splat}
      ${GLSL.detailNoise}
      ${GLSL.octaves}
      void main() {
        if (aroundEye.w > 0.0) {
          vec2 ndc = gl_FragCoord.xy / viewport * 2.0 - 1.0;
          vec3 d = normalize(forward + ndc.x * tanHalf.x * right + ndc.y * tanHalf.y * up);
          vec3 w = aroundEye.xyz;
          float sc = dot(w, d);
          float q = max(dot(w, w) - sc * sc, 0.0);
          if (!(q < 1.0)) discard;
          float a = 1.0 - exp(-tau * chord(q, -sc) / S0);
          if (!(a > 0.0)) discard;
          colour = vec4(max(fogColourTauSun.rgb + phaseCorrection(fogColourTauSun.a, d), vec3(0.0)) * a, a);
          detailOut = vec4(0.0, 0.0, 0.0, a);
          return;
        }
        float q = dot(corner, corner);
        if (q >= 1.0) discard;
        float a = 1.0 - exp(-tau * chord(q, -1.0) / S0);
        colour = vec4(radiance * a, a);
        float n = detailOctaves > 0 && a > 0.0 ? detailNoise((rel + eyeMod) / radius, detailOctaves) : 0.0;
        detailOut = vec4(n * a, a, 0.0, a);
      }`,
    blending: THREE.CustomBlending,
    blendSrc: THREE.OneFactor,
    blendDst: THREE.OneMinusSrcAlphaFactor,
    blendSrcAlpha: THREE.OneFactor,
    blendDstAlpha: THREE.OneMinusSrcAlphaFactor,
    transparent: true,
    depthTest: false,
    depthWrite: false,
  });

// The detail erosion of the clouds' accumulated opacity (render::detail, composite.rs):
// A' = erode(A, E · n), n = Σ w_k n_k / Σ w_k, the colour scaled by A'/A, laid over the
// sky and ground (premultiplied `over`).
const erosionMaterial = (clouds) =>
  new THREE.ShaderMaterial({
    glslVersion: THREE.GLSL3,
    uniforms: { cloud: { value: clouds.textures[0] }, detailTex: { value: clouds.textures[1] }, strength: { value: DETAIL_EROSION } },
    vertexShader: SCREEN_VERTEX,
    fragmentShader: /* glsl */ `
      precision highp float;
      uniform sampler2D cloud, detailTex;
      uniform float strength;
      out vec4 colour;
      void main() {
        ivec2 at = ivec2(gl_FragCoord.xy);
        vec4 c = texelFetch(cloud, at, 0);
        float a = c.a;
        if (a <= 0.0) discard;
        vec4 d = texelFetch(detailTex, at, 0);
        float n = d.y > 0.0 ? strength * clamp(d.x / d.y, 0.0, 1.0) : 0.0;
        float lo = n * (1.0 - a);
        float eroded = lo >= 1.0 ? 0.0 : clamp((a - lo) / (1.0 - lo), 0.0, a);
        colour = vec4(c.rgb * (eroded / a), eroded);
      }`,
    blending: THREE.CustomBlending,
    blendSrc: THREE.OneFactor,
    blendDst: THREE.OneMinusSrcAlphaFactor,
    depthTest: false,
    depthWrite: false,
  });

// The linear picture mapped for display (light.rs tone_map, sky.json's exposure).
const toneMaterial = (scene, exposure) =>
  new THREE.ShaderMaterial({
    glslVersion: THREE.GLSL3,
    uniforms: { scene: { value: scene }, exposure: { value: exposure }, toneOut: { value: true } },
    vertexShader: SCREEN_VERTEX,
    fragmentShader: /* glsl */ `
      precision highp float;
      uniform sampler2D scene;
      out vec4 colour;
      ${GLSL.tone}
      void main() { colour = vec4(tone(texelFetch(scene, ivec2(gl_FragCoord.xy), 0).rgb), 1.0); }`,
    depthTest: false,
    depthWrite: false,
  });

/** A sky.json for the view's sun: the given one, else the world clock's at t (its bucket's centre, as the tiles'). */
async function skyFor(t) {
  return client.json(params.sun ? `/v1/sky.json?sun=${params.sun.join(',')}` : `/v1/sky.json?t=${t}`);
}

async function billboards(world) {
  const sky = await skyFor(params.t);
  const sunDirection = sky.sun.direction;
  const cam = { x: cx, y: cy, z: cz, yaw: yawDeg, pitch: pitchDeg, fov: fovDeg };
  const tiles = planTiles(world, cam, innerWidth, innerHeight, {
    quality: params.quality,
    sun: sunDirection,
    layers: params.layer ? [params.layer] : undefined,
    maxTiles: MAX_TILES,
  });
  if (!tiles || tiles.length > MAX_TILES) throw new Error(`the view needs more than ${MAX_TILES} tiles (cloudscape render refuses it too)`);
  status.tiles = tiles.length;
  const at = { quality: params.quality, sun: params.sun };
  const atmosphere = skyUniformsThree(sky);
  const view = viewUniforms();
  const [w, h] = [innerWidth, innerHeight];

  const sceneTarget = new THREE.WebGLRenderTarget(w, h, { type: THREE.HalfFloatType, depthBuffer: false });
  const cloudTarget = new THREE.WebGLRenderTarget(w, h, { type: THREE.HalfFloatType, depthBuffer: false, count: 2 });
  for (const target of [sceneTarget, cloudTarget]) {
    for (const tex of target.textures) tex.minFilter = tex.magFilter = THREE.NearestFilter;
  }
  const shadowData = new Uint16Array(2 * TILE_COLUMNS * TILE_COLUMNS * Math.max(tiles.length, 1));
  const shadowMaps = new THREE.DataArrayTexture(shadowData, TILE_COLUMNS, TILE_COLUMNS, Math.max(tiles.length, 1));
  shadowMaps.format = THREE.RGFormat;
  shadowMaps.type = THREE.HalfFloatType;
  shadowMaps.minFilter = shadowMaps.magFilter = THREE.LinearFilter;
  const background = backgroundMaterial({
    ...atmosphere,
    ...view,
    sunRgb: { value: new THREE.Vector3(...sky.sun_rgb) },
    disc: { value: new THREE.Vector2(sky.sun_disc.angular_radius, sky.sun_disc.gain) },
    shadowMaps: { value: shadowMaps },
    shadowRects: { value: Array.from({ length: MAX_TILES }, () => new THREE.Vector4()) },
    shadowCount: { value: 0 },
    shadows: { value: cz > 0 && sunDirection[2] > 0 },
    far: { value: 1 },
    viewDistance: { value: VIEW_DISTANCE },
  });
  const wrap = (v) => v - 65536 * Math.floor(v / 65536);
  const cloudUniforms = {
    ...atmosphere,
    ...view,
    sunRgb: { value: new THREE.Vector3(...sky.sun_rgb) },
    albedo: { value: 0.9 },
    phase: { value: new THREE.Vector3(0.7, -0.2, 0.5) },
    octaves: { value: new THREE.Vector4(3, 0.5, 0.75, 0.5) },
    pixelAngle: { value: (2 * Math.tan(rad(fovDeg) / 2)) / w },
    eyeMod: { value: new THREE.Vector3(wrap(cx), wrap(cy), cz) },
    viewport: { value: new THREE.Vector2(w, h) },
  };
  const material = billboardMaterial(cloudUniforms);
  const backgroundScene = new THREE.Scene().add(screenQuad(background));
  const cloudScene = new THREE.Scene();
  const erosionScene = new THREE.Scene().add(screenQuad(erosionMaterial(cloudTarget)));
  const toneScene = new THREE.Scene().add(screenQuad(toneMaterial(sceneTarget.texture, atmosphere.exposure.value)));
  const screenCamera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0, 1);
  let loaded = [];
  let loadedFor = '';
  let mesh = null;

  /**
   * The tiles' keyframes holding t (held once fetched, the next ones prefetched past
   * each tile's prefetch point as deltas on them) and, when they change, the ground
   * shadow maps derived from them (each tile's from the tiles of its layer).
   */
  async function load(t) {
    const key = tiles.map((tile) => keyframeOf(world.layers[tile.layerIndex], tile.z, t, world.max_time).t0).join();
    if (key === loadedFor) return;
    loaded = await Promise.all(tiles.map((tile) => client.billboardTile(world, tile, { ...at, t })));
    loadedFor = key;
    status.keyframes = loaded.map((l) => [l.billboards.header.t0, l.billboards.header.t1]);
    status.forms = loaded.map((l) => l.billboards.header.form);
    const lit = loaded.find((l) => l.billboards.header.lighting)?.billboards.header.lighting;
    if (lit) {
      cloudUniforms.sunRgb.value.set(...lit.sunRgb);
      cloudUniforms.albedo.value = lit.albedo;
      cloudUniforms.phase.value.set(lit.phase.g1, lit.phase.g2, lit.phase.mix);
      cloudUniforms.octaves.value.set(lit.octaves.count, lit.octaves.a, lit.octaves.b, lit.octaves.c);
    }
    const held = loaded.map((l, i) => ({ layer: tiles[i].layer, base: world.layers[tiles[i].layerIndex].base, keyframe: l.billboards }));
    const n = TILE_COLUMNS * TILE_COLUMNS;
    held.forEach((target, i) => {
      const d = new ShadowDerivation(target);
      for (const source of held) if (source.layer === target.layer) d.add(source);
      const maps = d.finish();
      for (let j = 0; j < n; j++) {
        shadowData[2 * (i * n + j)] = THREE.DataUtils.toHalfFloat(maps.t0[j]);
        shadowData[2 * (i * n + j) + 1] = THREE.DataUtils.toHalfFloat(maps.t1[j]);
      }
      target.mean = [mean(maps.t0), mean(maps.t1)];
      target.maps = maps;
    });
    shadowMaps.needsUpdate = true;
    loaded.forEach((l, i) => {
      l.held = held[i];
      // Lit through the other layers above (the client's lightBeneathLayers, as
      // `cloudscape render` and the viewer draw them).
      const lit = lightBeneathLayers(held[i], held);
      l.drawn = { ...l.billboards, records: { ...l.billboards.records, colour: lit.colour, tauSun: lit.tauSun } };
    });
  }

  /** The frame at time t: the billboards moved by the rule and sorted, the shadows blended. */
  function build(t) {
    const layers = new Map();
    loaded.forEach((l, i) => {
      const k = l.billboards;
      const f = fraction(k.header.t0 ?? t, k.header.t1 ?? t, t);
      const [sx, sy] = shadowShift(k, l.held.base);
      background.uniforms.shadowRects.value[i].set(k.header.origin[0] - sx - cx, k.header.origin[1] - sy - cy, k.header.size, f);
      const m = Math.min(Math.max((1 - f) * l.held.mean[0] + f * l.held.mean[1], 0), 1);
      const e = layers.get(l.held.layer) || { sum: 0, n: 0 };
      layers.set(l.held.layer, { sum: e.sum + m, n: e.n + 1 });
    });
    background.uniforms.shadowCount.value = loaded.length;
    background.uniforms.far.value = [...layers.values()].reduce((p, e) => p * (e.sum / e.n), 1);

    const frames = loaded.map((l) => billboardsAt(l.drawn ?? l.billboards, t));
    const a = threeArrays(frames, { origin, eye });
    if (!mesh || mesh.instanceMatrix.count < a.count) {
      if (mesh) {
        cloudScene.remove(mesh);
        mesh.dispose();
      }
      mesh = new THREE.InstancedMesh(new THREE.PlaneGeometry(2, 2), material, Math.max(a.count, 1));
      mesh.frustumCulled = false;
      mesh.geometry.setAttribute('instColour', new THREE.InstancedBufferAttribute(new Float32Array(3 * mesh.count), 3));
      mesh.geometry.setAttribute('instTaus', new THREE.InstancedBufferAttribute(new Float32Array(2 * mesh.count), 2));
      cloudScene.add(mesh);
    }
    const m = new THREE.Matrix4();
    const taus = mesh.geometry.getAttribute('instTaus');
    for (let i = 0; i < a.count; i++) {
      const r = a.radii[i];
      m.makeScale(r, r, r).setPosition(a.positions[3 * i], a.positions[3 * i + 1], a.positions[3 * i + 2]);
      mesh.setMatrixAt(i, m);
      taus.array[2 * i] = a.splatTaus[i];
      taus.array[2 * i + 1] = a.tauSuns[i];
    }
    mesh.count = a.count;
    mesh.geometry.getAttribute('instColour').array.set(a.colours);
    mesh.instanceMatrix.needsUpdate = true;
    mesh.geometry.getAttribute('instColour').needsUpdate = true;
    taus.needsUpdate = true;
    status.instances = a.count;
  }

  /** Draws the frame: sky and ground, clouds, their erosion over them, the display mapping. */
  function draw() {
    renderer.autoClear = false;
    renderer.setRenderTarget(sceneTarget);
    renderer.render(backgroundScene, screenCamera);
    renderer.setRenderTarget(cloudTarget);
    renderer.setClearColor(0x000000, 0);
    renderer.clear();
    renderer.render(cloudScene, camera);
    renderer.setRenderTarget(sceneTarget);
    renderer.render(erosionScene, screenCamera);
    renderer.setRenderTarget(null);
    renderer.render(toneScene, screenCamera);
  }

  await load(params.t);
  build(params.t);
  return {
    tiles,
    draw,
    update: async (t) => {
      await load(t);
      build(t);
    },
  };
}

const mean = (a) => a.reduce((s, v) => s + v, 0) / a.length;

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
  let tiles;
  let update = null;
  let draw = () => renderer.render(scene, camera);
  if (params.mode === 'billboards') {
    const b = await billboards(world);
    ({ tiles, update, draw } = b);
  } else {
    tiles = tilesAround(world, params.layer || world.layers[0].name, params.level, cx, cy, params.radius);
    status.tiles = tiles.length;
    await volumes(world, tiles);
  }
  let t = params.t;
  const show = () => {
    draw();
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
