// cloudscape viewer: a thin WebGL2 client of the tile server, built on its JS client
// (`/client/cloudscape.js`, clients/js): one decoder, one keyframe rule, one fetch
// policy for the viewer and for games.
//
// It draws what `cloudscape render` draws (crates/cloudscape-core/src/view/held.rs,
// render::composite, render::scene::background) from the same bytes: for the tiles
// around the camera, the shaded metaball instances (`billboards.bin`) and the sky of
// the tiles' sun (`/v1/sky.json`). Camera-facing billboards, each with the splat
// profile of its own optical depth evaluated per pixel, sorted back to front and
// blended over the sky and a shadowed ground plane, in linear radiance; the picture
// is tone-mapped once at the end (`exposure` from sky.json). The ground shadow is
// not fetched: each tile's maps are derived from the billboards of the layer's tiles
// the view holds (the client's ShadowDerivation, the rule of view/held.rs), a frame's
// budget at a time. The same maps light each billboard through the other layers
// above it (the client's lightBeneathLayers, docs/formats.md "Layers above"), applied
// to its two ends when the instances are built. Level choice follows the server's renderer (src/render/scene.rs
// `plan`): a quadtree per layer, split while a column would span more than the
// preset's `lod_pixels`, out to the renderer's view distance.
//
// Tile products are keyframes (src/world/keyframe.rs): a tile of level z is fetched at
// t0 = floor(t / span) · span, span the layer's `keyframe_spans[min(z, 4)]` from
// discovery, so its URL is the same for the whole span and `immutable`. A tile's first
// keyframe is `billboards.bin` (self-contained); every later one is
// `billboards.delta.bin`, decoded on the keyframe before it, which the client holds
// decoded. Between t0 and t1 = t0 + span the viewer animates it by the documented rule
// (docs/formats.md, "Animation"): with f = (t − t0) / span, each billboard moves by its
// wind velocity · (t − t0), and its centre optical depth, colour and sun optical depth
// are linear in f; the shadow maps of the two ends blend by f. Past a point in the
// second half of a span (each tile's own, prefetchAt: players sharing the clock do not
// all ask at once) the next keyframe is prefetched, so the boundary costs no wait.
//
// Immutable bodies are kept (in memory, and in the Cache Storage API across reloads)
// and never asked for again. Anything else revalidates with the ETag it was last
// given; a 304 reuses the stored bytes. Tiles that leave the view are dropped.
//
// The drawn time follows the world clock (discovery's `clock`, as a player's client
// does) unless the URL gives `t` or the time slider is moved. State can be given in
// the URL: ?world=&t=&camera=X,Y,Z,YAW,PITCH,FOV&quality=&sun=AZ,EL&layers=a,b
// &view=METRES&weather=off&rate=R (R world seconds per second while following the
// clock, instead of the clock's own rate). The page keeps the URL up to date.

import {
  CloudscapeClient,
  GLSL,
  LOD_PIXELS,
  MAX_DETAIL_OCTAVES,
  MIN_WAVELENGTH_PIXELS,
  SHADOW_FADE_START,
  ShadowDerivation,
  TILE_COLUMNS,
  VIEW_DISTANCE,
  cameraBasis as basis,
  fraction,
  keyframeOf,
  keyframeSun,
  lightBeneathLayers,
  planTiles,
  prefetchAt,
  shadowShift,
  skyUniforms,
  worldClock,
} from '/client/cloudscape.js';

// ---------------------------------------------------------------------------
// Constants shared with the server (src/render/*.rs).
// ---------------------------------------------------------------------------

/**
 * ShadingParams::default() (src/render/light.rs): what a version-1 billboards.bin (no
 * lighting in its header) is drawn with. Later versions carry albedo, phase, octaves
 * and the sun's radiance in their header; the detail erosion strength is the viewer's
 * own (render::Quality::light's, the same in every preset).
 */
const SHADING = {
  albedo: 0.9, sunIntensity: 1.2, ambient: [0.30, 0.34, 0.42], g1: 0.7, g2: -0.2, mix: 0.5,
  octaves: [3, 0.5, 0.75, 0.5], detailErosion: 0.3,
};
/** Most tiles (over all layers) kept at once; past it the level choice gets coarser. */
const MAX_TILES = 48;
/** Requests in flight at once (the server computes tiles on a bounded queue). */
const MAX_IN_FLIGHT = 4;
/**
 * Floats per instance in the GPU buffer: centre xyz at t0 and radius; velocity xy, t0
 * (relative to `timeOrigin`) and span; colour rgb at t0; colour rgb at t1; centre
 * optical depth at t0, t1; sun optical depth at t0, t1.
 */
const INSTANCE_FLOATS = 18;
/** Bodies kept in memory (precipitation maps, skies; billboards are held decoded). */
const MAX_HELD = 8 * MAX_TILES;
/** Cache Storage bucket of immutable and revalidatable responses. */
const CACHE_NAME = 'cloudscape-v1';
/** Main-thread time per frame given to deriving ground shadows, ms (at least one step a frame). */
const SHADOW_BUDGET_MS = 6;
/** Balls a shadow derivation adds between two looks at the clock. */
const SHADOW_STEP = 2000;
/** A frame drawn within this (ms) is followed by the next at once when only the time moved. */
const TIME_FRAME_MS = 50;
/** Least wall time between two sorts of the billboards while only the time moves, ms. */
const RESORT_MS = 250;
/** Lightning (issue 24): the world-time window and half side (m) of one /lightning query. */
const LIGHTNING_WINDOW = 300;
const LIGHTNING_HALF_SIDE = 20000;
/** How long a flash shows, wall-clock ms; a time jump longer than this (s) flashes nothing. */
const FLASH_MS = 400;
const FLASH_MAX_JUMP = 60;

// ---------------------------------------------------------------------------
// Small maths.
// ---------------------------------------------------------------------------

const rad = (d) => (d * Math.PI) / 180;
const clamp = (v, a, b) => Math.min(b, Math.max(a, v));
const smoothstep = (e0, e1, x) => {
  const t = clamp((x - e0) / (e1 - e0), 0, 1);
  return t * t * (3 - 2 * t);
};
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

/**
 * Lighting of the current sky (`GET /v1/sky.json`, src/products/sky.rs): the server's
 * atmosphere for the sun bucket the tiles are shaded for, so the sky, sun colour,
 * ambient and aerial perspective are those `cloudscape render` draws.
 */
function lighting() {
  const s = skyInfo;
  return { dir: s.sun.direction, sunRgb: s.sun_rgb, sunGround: s.sun_rgb_ground, above: s.sky_ambient_above };
}

// ---------------------------------------------------------------------------
// State: URL parameters, then the controls.
// ---------------------------------------------------------------------------

const query = new URLSearchParams(location.search);

function parseNumbers(s, n) {
  if (!s) return null;
  const v = s.split(',').map(Number);
  return v.length === n && v.every(Number.isFinite) ? v : null;
}

const DEFAULT_CAMERA = [12800, -6000, 900, 0, 6, 75];
const camArr = parseNumbers(query.get('camera'), 6) || DEFAULT_CAMERA;
const fixedT = query.get('t') !== null && query.get('t') !== '' && Number.isFinite(Number(query.get('t'))) ? Number(query.get('t')) : null;
const state = {
  world: query.get('world') || 'default',
  quality: LOD_PIXELS[query.get('quality')] ? query.get('quality') : 'fast',
  /** The drawn time, world seconds (while following the clock: the clock's now). */
  t: fixedT ?? 43200,
  /** Whether the drawn time follows the world clock (no `t` in the URL, the slider untouched). */
  follow: fixedT === null,
  /** World seconds per second while following the clock (`rate=`), or null for the clock's own. */
  rate: Number(query.get('rate')) > 0 ? Number(query.get('rate')) : null,
  camera: { x: camArr[0], y: camArr[1], z: camArr[2], yaw: camArr[3], pitch: camArr[4], fov: camArr[5] },
  /** Manual sun [az, el], or null to follow the world clock (the server's choice). */
  sun: parseNumbers(query.get('sun'), 2),
  /** Names of the layers drawn (`layers=` alone: none), or null for all. */
  layers: query.has('layers') ? query.get('layers').split(',').filter(Boolean) : null,
  viewDistance: Number(query.get('view')) > 0 ? Number(query.get('view')) : VIEW_DISTANCE,
  /** Rain, snow and lightning drawn (`weather=off`: clouds only, and fewer requests). */
  weather: query.get('weather') !== 'off',
  playing: false,
};

/** The client every request goes through; tile URLs it asks for are listed in `stats.urls`. */
const client = new CloudscapeClient('', {
  quality: state.quality,
  maxBodies: MAX_HELD,
  // No Cache Storage (an insecure context): memory only.
  cache: (async () => (typeof caches === 'undefined' ? null : caches.open(CACHE_NAME)))().catch(() => null),
  fetch: (url, init) => {
    if (url.includes('/tiles/')) viewerStats.urls.push(url);
    return fetch(url, init);
  },
});

/** Counters of the viewer itself (the HUD shows them, tests read them through `stats`). */
const viewerStats = {
  /** Bytes on the wire (Resource Timing transferSize: headers + encoded body). */
  transferBytes: 0,
  failures: 0,
  drawCalls: 0,
  /** Frames drawn (a frame that would show what the last one showed is not drawn). */
  frames: 0,
  billboards: 0,
  /** Whether the detail-erosion pass ran in the last frame (needs float render targets). */
  erosion: false,
  /** Whether the last frame was drawn in linear radiance and mapped once (needs float render targets). */
  linear: false,
  frameMs: 0,
  /** Tile URLs requested, in order. */
  urls: [],
  /** Ground shadow maps derived, and the main-thread time they took (ms). */
  shadows: 0,
  shadowMs: 0,
  /** Drawn tiles with a precipitation map, and the rain or snow at the eye (mm/h). */
  precipitationTiles: 0,
  eyeRate: 0,
  eyeSnow: false,
  /** Strikes known around the view (the last /lightning answer), and flashes shown. */
  strikes: 0,
  flashes: 0,
};

/** The viewer's counters, and the client's under the names the HUD and tests read. */
const stats = Object.defineProperties(viewerStats, {
  requests: { get: () => client.stats.requests, enumerable: true },
  /** Responses with a body (200). */
  fetched: { get: () => client.stats.fetched, enumerable: true },
  /** 304 answers to If-None-Match: the stored bytes were reused. */
  revalidations: { get: () => client.stats.revalidated, enumerable: true },
  /** Immutable bodies (memory or Cache Storage) and held keyframes used again without a request. */
  reused: { get: () => client.stats.reused, enumerable: true },
  /** Next-keyframe products asked for ahead of need. */
  prefetched: { get: () => client.stats.prefetched, enumerable: true },
  /** Delta keyframes (billboards.delta.bin) fetched. */
  deltas: { get: () => client.stats.deltas, enumerable: true },
  /** Decoded body bytes of 200 responses. */
  bodyBytes: { get: () => client.stats.bodyBytes, enumerable: true },
});

let worldInfo = null;
/** The world time of the world's clock now (worldClock of its discovery). */
let clockNow = null;
/** The parsed /v1/sky.json of the current sun, its URL, and its radiance table as a texture. */
let skyInfo = null;
let skyUrlLoading = '';
let skyTexture = null;
/** The uniform values of the loaded sky (the client's skyUniforms). */
let skyValues = null;

performance.setResourceTimingBufferSize?.(100000);
new PerformanceObserver((list) => {
  for (const e of list.getEntries()) viewerStats.transferBytes += e.transferSize || 0;
}).observe({ type: 'resource', buffered: true });

async function decodeImage(bytes, type) {
  return createImageBitmap(new Blob([bytes], { type }), {
    premultiplyAlpha: 'none',
    colorSpaceConversion: 'none',
  });
}

// ---------------------------------------------------------------------------
// WebGL.
// ---------------------------------------------------------------------------

const canvas = document.getElementById('view');
const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true, alpha: false });
if (!gl) throw new Error('WebGL2 is not available in this browser');

function compile(vs, fs) {
  const shader = (type, src) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  };
  const p = gl.createProgram();
  gl.attachShader(p, shader(gl.VERTEX_SHADER, vs));
  gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fs));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  const uniforms = {};
  for (let i = 0; i < gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS); i++) {
    const name = gl.getActiveUniform(p, i).name;
    uniforms[name] = gl.getUniformLocation(p, name);
  }
  return { program: p, u: uniforms };
}

// The server's light as GLSL (the client's GLSL chunks): the display mapping, the
// atmosphere of sky.json, the ground, the octaves' phase correction, the splat
// profile and the detail noise. The scene is drawn in linear radiance into a float
// target and mapped once at the end (toneProgram), so blending happens in radiance as
// in the server's compositor; without float targets each pass maps its own output
// (`display`), which blends in display values instead.
const { tone: TONE, atmosphere: ATMOSPHERE, ground: GROUND, octaves: OCTAVES, splat: SPLAT, detailNoise: DETAIL_NOISE } = GLSL;

/** A vertex shader drawing one triangle over the whole screen (3 vertices, no buffers). */
const FULL_SCREEN = `#version 300 es
  void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2)) * 2.0 - 1.0;
    gl_Position = vec4(p, 0.0, 1.0);
  }`;

// Sky (with the sun's disc) and ground, per pixel from the view ray
// (scene::background, Lighting::background). The ground's sun transmittance is the
// product of the tiles' shadows at the ground point (`shadowTex`, shadowProgram; 1
// where no tile's shadow falls) turned into `far`, the mean shadow of the tiles drawn,
// over the last 30 % of the view distance, beyond which the clouds are unknown; so
// the far ground has neither a hard edge nor a sunlit band.
const skyProgram = compile(
  `#version 300 es
  out vec2 ndc;
  void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2)) * 2.0 - 1.0;
    ndc = p;
    gl_Position = vec4(p, 0.0, 1.0);
  }`,
  `#version 300 es
  precision highp float;
  in vec2 ndc;
  uniform vec3 forward, right, up;
  uniform vec2 tanHalf;
  uniform vec3 sunRgb;
  uniform vec2 disc; // angular radius, gain
  uniform float eyeZ;
  uniform sampler2D shadowTex; // the product of the tiles' shadows at each pixel's ground point (R)
  uniform bool shadows;        // the eye above the ground and the sun above the horizon
  uniform float far, viewDistance;
  out vec4 colour;
  ${TONE}
  ${ATMOSPHERE}
  ${GROUND}
  void main() {
    vec3 d = normalize(forward + ndc.x * tanHalf.x * right + ndc.y * tanHalf.y * up);
    vec3 c;
    if (d.z >= 0.0 || eyeZ <= 0.0) {
      c = skyRadiance(d);
      float angle = acos(clamp(dot(d, sunDir), -1.0, 1.0));
      float k = 1.0 - smoothstep(0.75 * disc.x, 1.25 * disc.x, angle);
      c += k * disc.y * sunRgb;
    } else {
      vec3 ray = d * (eyeZ / -d.z);
      float t = 1.0;
      if (shadows) {
        float fade = smoothstep(${SHADOW_FADE_START.toFixed(2)} * viewDistance, viewDistance, length(ray.xy));
        float near = fade < 1.0 ? texelFetch(shadowTex, ivec2(gl_FragCoord.xy), 0).r : far;
        t = near + fade * (far - near);
      }
      c = ground(ray, eyeZ, t);
    }
    colour = vec4(display(c), 1.0);
  }`,
);

// Ground shadow of one tile, multiplied into the shadow target (cleared to 1): T read
// from the tile's derived maps (R at its keyframe's t0, G at t1, blended by the drawn
// time), bilinearly between column centres, where the sun ray from the ground point
// crosses the layer's base: the quad is the tile shifted away from the sun
// (render::tile::shadow_lookup after shadow_shift). Outside every quad T stays 1, as
// GroundShadow::at is 1 outside its tile.
const shadowProgram = compile(
  `#version 300 es
  uniform mat4 viewProj;
  uniform vec4 rect; // x0, y0 relative to the eye; side; eye altitude
  out vec2 uv;
  void main() {
    vec2 q = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1));
    uv = q; // the derived maps' row 0 is the southern edge
    gl_Position = viewProj * vec4(rect.xy + q * rect.z, -rect.w, 1.0);
  }`,
  `#version 300 es
  precision highp float;
  in vec2 uv;
  uniform sampler2D shadow;  // R: transmittance at the keyframe's t0, G: at t1 (RG16F)
  uniform float shadowF;     // where the drawn time falls in the tile's span
  out vec4 colour;
  void main() {
    vec4 s = texture(shadow, uv);
    colour = vec4(mix(s.r, s.g, shadowF));
  }`,
);

// The linear picture mapped for display (light.rs `tone_map`), once per pixel.
const toneProgram = compile(
  FULL_SCREEN,
  `#version 300 es
  precision highp float;
  uniform sampler2D scene;
  out vec4 colour;
  ${TONE}
  void main() { colour = vec4(tone(texelFetch(scene, ivec2(gl_FragCoord.xy), 0).rgb), 1.0); }`,
);

// Extinction of rain and snow, per km, at a rate R (mm/h, water equivalent). Rain:
// σ = 0.25·R^0.63 (Atlas 1953, optical extinction by rainfall; geometric optics on a
// Marshall–Palmer drop spectrum gives the same exponent, π·N0/Λ³ = 0.37·R^0.63).
// Snow: σ = 3·R^0.7 (snow hides far more per mm of water). By Koschmieder's
// visibility V = 3.9/σ that is 6.5 km at 4 mm/h, 2 km at 27 mm/h, 0.9 km at 100 mm/h
// of rain. The haze the drops make is lit by the light under the clouds; drops
// scatter mostly forward (geometric optics, asymmetry g ≈ 0.87), so the haze carries
// much of the light of what lies behind it: looking down, the ground (albedo well
// under 1), so it is darker there than toward the horizon (dz: the view ray's z).
const PRECIPITATION = `
  float precipitationPerKm(float rate, bool snow) {
    return snow ? 3.0 * pow(rate, 0.7) : 0.25 * pow(rate, 0.63);
  }
  vec3 precipitationHaze(vec3 hazeRgb, float dz) { return hazeRgb * (1.0 - 0.4 * max(-dz, 0.0)); }`;

/** The rain law of PRECIPITATION on the CPU: extinction per metre at `rate` mm/h. */
function precipitationPerMetre(rate, snow) {
  return (snow ? 3 * rate ** 0.7 : 0.25 * rate ** 0.63) * 1e-3;
}

// Camera-facing billboards (premultiplied `over`), as render::composite draws them.
// The opacity at a pixel is 1 − exp(−τ P(q)), τ the ball's centre optical depth and
// P(q) = S(√q)/S(0) the splat profile at the pixel's squared distance q from the
// centre in radii (S the line integral of Wyvill's field function through the unit
// ball, render::splats::line_integral), evaluated per pixel as the server's
// compositor does, whatever the billboard's size on screen. The colour is the
// pre-shaded (isotropic) colour plus the phase correction of the scattering octaves
// (Lighting::phase_correction, src/render/light.rs):
// albedo · sun · Σ_{i<N} bⁱ (p(cos θ; cⁱ g) − 1) e^{−aⁱ τ_sun}, seen through the air
// between the eye and the centre.
//
// A ball whose centre lies within AROUND_EYE_RADII radii of the eye is not a quad: it
// covers the whole screen and each pixel takes the part of the ball's chord along its
// ray that lies in front of the eye (line_integral_beyond), shaded for that ray's
// direction and not hazed (composite.rs `Draw::AroundEye`): inside a cloud layer that
// is fog, thicker toward nearby centres. Other billboards nearer than NEAR_CLIP_RADII
// radii along the view axis lie beside the eye and are not drawn.
//
// When the erosion pass runs each billboard also writes, into a second target with the
// same `over`, (n_k · α, α, 0, α): n_k the detail noise at the fragment's own point
// on billboard k's plane (first wavelength k's radius, octaves while one spans
// MIN_WAVELENGTH_PIXELS of k's pixel footprint, distance · pixelAngle; n_k = 0 when
// not even the first does). Blended back to front that sums Σ_k w_k n_k and Σ_k w_k
// with w_k = (1 − A)·α_k, the weights src/render/composite.rs accumulates front to
// back; a ball around the eye writes (0, 0, 0, α): fog, not an edge, it weighs
// nothing. Points are taken relative to the eye plus the eye's position modulo
// 65536 m, so f32 noise never sees raw world metres.
//
// Each instance holds both ends of its keyframe span and is drawn at `time` by the
// animation rule (render::keyframe): moved by its velocity, its centre optical depth
// τ, colour and τ_sun linear in f.
const AROUND_EYE_RADII = 2.0;
const NEAR_CLIP_RADII = 0.5;
const billboardProgram = compile(
  `#version 300 es
  layout(location = 0) in vec4 centreRadius; // centre at t0 relative to the buffer origin; radius
  layout(location = 1) in vec4 motion;       // velocity xy (m/s); t0 relative to timeOrigin; span (s)
  layout(location = 2) in vec3 rgb0;         // colour at t0, isotropic phase (linear)
  layout(location = 3) in vec3 rgb1;         // colour at t1
  layout(location = 4) in vec4 taus;         // centre optical depth at t0, t1; sun optical depth at t0, t1
  uniform float time;       // drawn time relative to timeOrigin, seconds
  uniform mat4 viewProj;
  uniform vec3 eye, forward, right, up, sunRgb;
  uniform float albedo;
  uniform vec3 phase; // g1, g2, mix
  uniform vec4 octaves; // N, a, b, c
  uniform float pixelAngle; // radians per pixel
  uniform bool detail;      // whether the erosion pass runs
  uniform vec4 flashAt;     // a lightning flash: its light relative to the eye (xyz), gain (w)
  // Rain or snow where the eye stands: extinction per metre (0 when dry), the
  // altitude of its streak top (no precipitation above) and the lit haze colour.
  uniform float rainSigma, rainTop;
  uniform vec3 rainHaze;
  out vec2 corner;
  out vec3 radiance;
  out vec3 rel;
  flat out float radius;
  flat out float tau;
  flat out int detailOctaves;
  // A ball around the eye: its centre relative to the eye, in radii (w: 1), its
  // pre-shaded colour and sun optical depth; w = 0 for a quad.
  flat out vec4 aroundEye;
  flat out vec4 fogColourTauSun;
  ${ATMOSPHERE}
  ${OCTAVES}
  ${PRECIPITATION}
  void main() {
    corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1)) * 2.0 - 1.0;
    float span = motion.w;
    float since = clamp(time - motion.z, 0.0, span);
    float f = span > 0.0 ? since / span : 0.0;
    tau = mix(taus.x, taus.y, f);
    radius = centreRadius.w;
    vec3 c = centreRadius.xyz + vec3(motion.xy * since, 0.0) - eye;
    float dist = length(c);
    aroundEye = vec4(0.0);
    // Absent at this time (it forms or vanishes during the span), or beside the eye.
    if (!(tau > 0.0) || !(radius > 0.0) || (dist >= ${AROUND_EYE_RADII.toFixed(1)} * radius && dot(c, forward) < ${NEAR_CLIP_RADII.toFixed(1)} * radius)) {
      gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
      return;
    }
    vec3 rgb = mix(rgb0, rgb1, f);
    float tauSun = mix(taus.z, taus.w, f);
    if (dist < ${AROUND_EYE_RADII.toFixed(1)} * radius) {
      aroundEye = vec4(c / radius, 1.0);
      fogColourTauSun = vec4(rgb, tauSun);
      rel = vec3(0.0);
      detailOctaves = 0;
      radiance = vec3(0.0);
      gl_Position = vec4(corner, 0.0, 1.0);
      return;
    }
    vec3 p = c + (corner.x * right + corner.y * up) * radius;
    rel = p;
    // detail::octaves_for(radius, metres per pixel at the billboard's distance).
    float mpp = dot(c, forward) * pixelAngle;
    float wl = radius;
    detailOctaves = 0;
    while (detail && detailOctaves < ${MAX_DETAIL_OCTAVES} && wl >= ${MIN_WAVELENGTH_PIXELS.toFixed(1)} * mpp) {
      detailOctaves++;
      wl *= 0.5;
    }
    gl_Position = viewProj * vec4(p, 1.0);
    radiance = max(rgb + phaseCorrection(tauSun, normalize(c)), vec3(0.0));
    radiance += flashAt.w * vec3(1.4, 1.5, 1.8) * exp(-length(c - flashAt.xyz) / 2500.0);
    // Aerial perspective by the billboard's distance (composite.rs: c · T + L_in).
    vec3 T, L;
    aerial(c, eye.z, centreRadius.z, 1.0, T, L);
    radiance = radiance * T + L;
    // The eye stands in rain: the billboard is seen through the rain between them, as
    // far as it lies below the streak top (the rate at the eye stands for the whole
    // stretch; the boxes haze what lies behind). Beer–Lambert, lit by the rain's haze.
    if (rainSigma > 0.0) {
      float below = c.z > 0.0 ? clamp((rainTop - eye.z) / c.z, 0.0, 1.0) : 1.0;
      float tr = exp(-rainSigma * dist * below);
      radiance = radiance * tr + precipitationHaze(rainHaze, c.z / max(dist, 1e-6)) * (1.0 - tr);
    }
  }`,
  `#version 300 es
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
  uniform vec3 eyeMod; // eye position modulo 65536 m (z as is)
  uniform vec3 forward, right, up, sunRgb, sunDir;
  uniform vec2 tanHalf, viewport;
  uniform float albedo;
  uniform vec3 phase;
  uniform vec4 octaves;
  layout(location = 0) out vec4 colour;
  layout(location = 1) out vec4 detailOut;
  ${TONE}
  ${DETAIL_NOISE}
  ${OCTAVES}
  ${SPLAT}
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
      vec3 c = max(fogColourTauSun.rgb + phaseCorrection(fogColourTauSun.a, d), vec3(0.0));
      colour = vec4(display(c) * a, a);
      detailOut = vec4(0.0, 0.0, 0.0, a);
      return;
    }
    float q = dot(corner, corner);
    if (q >= 1.0) discard;
    float a = 1.0 - exp(-tau * chord(q, -1.0) / S0);
    colour = vec4(display(radiance) * a, a);
    float n = detailOctaves > 0 && a > 0.0 ? detailNoise((rel + eyeMod) / radius, detailOctaves) : 0.0;
    detailOut = vec4(n * a, a, 0.0, a);
  }`,
);

// Detail erosion of the accumulated cloud opacity (src/render/detail.rs and
// composite.rs): A' = erode(A, E · n) with Nubis's remap and the colour scaled by
// A'/A, where n = Σ_k w_k n_k / Σ_k w_k is the weighted mean of the billboards' own
// detail noise (see billboardProgram). Averaging the noise values rather than taking
// the noise at the weighted mean point keeps rims where near and far billboards
// overlap free of contour ripples: that point sweeps along the view ray through many
// wavelengths within a few pixels, each n_k is smooth across the screen.
const erosionProgram = compile(
  FULL_SCREEN,
  `#version 300 es
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
);

// Precipitation under the clouds (issue 24): each drawn tile whose layer precipitates
// is a box from the ground up to its layer's top. Its back faces ray-march the view
// ray's stretch inside the box through precipitation.png: below each column's streak
// top (B) the air holds rain or snow of the column's rate (R), extinction after
// PRECIPITATION, lit by the sky under the clouds. The march ends at the ground or
// where the ray leaves the box, so it hazes the sky and the ground by their own
// distance; it is drawn before the billboards, which take the rain between the eye
// and themselves on their own (billboardProgram's rain uniforms).
const rainProgram = compile(
  `#version 300 es
  uniform mat4 viewProj;
  uniform vec3 boxMin, boxSize; // relative to the eye
  out vec3 rel;
  const int CORNERS[36] = int[36](0, 1, 3, 0, 3, 2, 4, 6, 7, 4, 7, 5, 0, 4, 5, 0, 5, 1,
                                  2, 3, 7, 2, 7, 6, 0, 2, 6, 0, 6, 4, 1, 5, 7, 1, 7, 3);
  void main() {
    int c = CORNERS[gl_VertexID];
    vec3 q = vec3(float(c & 1), float((c >> 1) & 1), float((c >> 2) & 1));
    rel = boxMin + q * boxSize;
    gl_Position = viewProj * vec4(rel, 1.0);
  }`,
  `#version 300 es
  precision highp float;
  in vec3 rel;
  uniform sampler2D rain;
  uniform vec3 boxMin, boxSize;
  uniform float eyeZ, layerBase, layerThickness, snowLevel, viewDistance;
  uniform vec3 hazeRgb;
  out vec4 colour;
  ${TONE}
  ${PRECIPITATION}
  void main() {
    vec3 d = normalize(rel);
    vec3 inv = 1.0 / mix(d, vec3(1e-9), lessThan(abs(d), vec3(1e-9)));
    vec3 a = boxMin * inv, b = (boxMin + boxSize) * inv;
    vec3 lo = min(a, b), hi = max(a, b);
    float tIn = max(max(lo.x, lo.y), lo.z), tOut = min(min(hi.x, hi.y), hi.z);
    float tHere = length(rel);
    // The front face of a box in front of the eye: its back face draws the stretch.
    if (tIn > 0.0 && abs(tHere - tIn) < abs(tHere - tOut)) discard;
    float t0 = max(tIn, 0.0), t1 = min(tOut, viewDistance);
    if (t1 <= t0) discard;
    const int N = 16;
    float ds = (t1 - t0) / float(N);
    float jitter = fract(sin(dot(gl_FragCoord.xy, vec2(12.9898, 78.233))) * 43758.5453);
    float tau = 0.0;
    for (int i = 0; i < N; i++) {
      vec3 p = d * (t0 + (float(i) + jitter) * ds);
      vec2 uv = (p.xy - boxMin.xy) / boxSize.xy;
      vec4 v = texture(rain, vec2(uv.x, 1.0 - uv.y)); // row 0 is the northern edge
      if (v.a <= 0.0) continue;
      float z = p.z + eyeZ;
      if (z > layerBase + v.b * layerThickness) continue; // above the streak top
      float r = v.r / max(v.a, 1e-3); // un-blended from dry neighbours by the filter
      float rate = 100.0 * r * r;
      tau += v.a * precipitationPerKm(rate, z >= snowLevel) * 1e-3 * ds;
    }
    float alpha = 1.0 - exp(-tau);
    colour = vec4(display(precipitationHaze(hazeRgb, d.z)) * alpha, alpha);
  }`,
);

// Streaks where the eye stands in rain or snow: falling lines (rain) or drifting
// flakes (snow) over the screen, as many as the rate at the eye asks for. The haze
// around the eye is the boxes' (it grows with distance). Drawn over the mapped
// picture, in display values.
const streakProgram = compile(
  FULL_SCREEN,
  `#version 300 es
  precision highp float;
  uniform vec2 viewport;
  uniform float time, rate, snow;
  uniform vec3 hazeRgb;
  out vec4 colour;
  ${TONE}
  float hash(float n) { return fract(sin(n * 127.1) * 43758.5453); }
  void main() {
    vec2 uv = gl_FragCoord.xy / viewport.y;
    float fill = clamp(0.15 + 0.35 * log(1.0 + rate), 0.0, 1.0); // share of columns with a streak
    float a = 0.0;
    for (int layer = 0; layer < 3; layer++) {
      float l = float(layer);
      float columns = (snow > 0.5 ? 40.0 : 50.0) * (1.0 + 0.8 * l);
      vec2 q = uv * columns;
      if (snow < 0.5) q.x += q.y * 0.12; // rain slants with the wind
      float col = floor(q.x);
      float h = hash(col + 31.0 * l);
      if (h > fill) continue;
      float speed = snow > 0.5 ? 0.12 + 0.04 * l : 1.6 + 0.5 * l; // screen heights per second
      float y = fract(uv.y * (snow > 0.5 ? 3.0 : 1.0) + time * speed + 7.0 * h);
      float x = fract(q.x) - 0.5 + (snow > 0.5 ? 0.3 * sin(time * 1.3 + 6.0 * h) : 0.0);
      // At least about a pixel across (thinner lines alias into dots).
      float w = max(snow > 0.5 ? 0.18 : 0.05, 0.7 * columns / viewport.y);
      float across = 1.0 - smoothstep(0.0, w, abs(x));
      float along = snow > 0.5 ? 1.0 - smoothstep(0.0, 0.02, abs(y - 0.5))
                               : smoothstep(0.0, 0.05, y) * (1.0 - smoothstep(0.05, 0.25, y));
      a = max(a, across * along * (0.55 - 0.12 * l));
    }
    // The haze of the rain itself is the boxes' (it grows with distance); the streaks
    // are the drops close by, lit a little brighter than the haze.
    colour = vec4(tone(hazeRgb * 3.0) * a, a);
  }`,
);

// Lightning: a bolt (cloud-to-ground), drawn as a jagged line into the scene (radiance
// that maps to near white at full gain), and the flash lighting the air around the
// viewer (added over the mapped picture).
const boltProgram = compile(
  `#version 300 es
  layout(location = 0) in vec3 position; // relative to the eye
  uniform mat4 viewProj;
  void main() { gl_Position = viewProj * vec4(position, 1.0); }`,
  `#version 300 es
  precision highp float;
  uniform float gain;
  out vec4 colour;
  ${TONE}
  void main() { colour = vec4(display(vec3(0.85, 0.9, 1.0) * 4.0 * gain), 0.0); }`,
);
const boltBuffer = gl.createBuffer();
const boltVao = gl.createVertexArray();
gl.bindVertexArray(boltVao);
gl.bindBuffer(gl.ARRAY_BUFFER, boltBuffer);
gl.enableVertexAttribArray(0);
gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 12, 0);
gl.bindVertexArray(null);

const veilProgram = compile(
  FULL_SCREEN,
  `#version 300 es
  precision highp float;
  uniform vec3 rgb;
  out vec4 colour;
  void main() { colour = vec4(rgb, 0.0); }`,
);

/** Whether float textures can be drawn into: the linear scene, the clouds' erosion pass. */
const floatTargets = gl.getExtension('EXT_color_buffer_float');
/** Offscreen targets by name: { w, h, target: { fb, textures } or null when incomplete }. */
const targets = new Map();
const RGBA16F = () => [gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT];

/**
 * The offscreen target `name` of `w` × `h` pixels with one texture (colour attachment)
 * per format [internal, format, type], made again when the size changes; null when
 * the implementation cannot draw into it.
 */
function offscreen(name, w, h, formats) {
  const held = targets.get(name);
  if (held && held.w === w && held.h === h) return held.target;
  if (held && held.target) {
    gl.deleteFramebuffer(held.target.fb);
    held.target.textures.forEach((t) => gl.deleteTexture(t));
  }
  const textures = formats.map(([internal, format, type]) => {
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, format, type, null);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    return t;
  });
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  textures.forEach((t, i) => gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, gl.TEXTURE_2D, t, 0));
  gl.drawBuffers(textures.map((_, i) => gl.COLOR_ATTACHMENT0 + i));
  const ok = gl.checkFramebufferStatus(gl.FRAMEBUFFER) === gl.FRAMEBUFFER_COMPLETE;
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  if (!ok) {
    gl.deleteFramebuffer(fb);
    textures.forEach((t) => gl.deleteTexture(t));
  }
  const target = ok ? { fb, textures } : null;
  targets.set(name, { w, h, target });
  return target;
}

const billboardVao = gl.createVertexArray();
const instanceBuffer = gl.createBuffer();
gl.bindVertexArray(billboardVao);
gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
const stride = INSTANCE_FLOATS * 4;
// centreRadius, motion, rgb0, rgb1, taus: [location, floats, first float].
for (const [loc, size, at] of [[0, 4, 0], [1, 4, 4], [2, 3, 8], [3, 3, 11], [4, 4, 14]]) {
  gl.enableVertexAttribArray(loc);
  gl.vertexAttribPointer(loc, size, gl.FLOAT, false, stride, at * 4);
  gl.vertexAttribDivisor(loc, 1);
}
gl.bindVertexArray(null);
const emptyVao = gl.createVertexArray();

function texture(image, filter) {
  const tex = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
  gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE, image);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  return tex;
}

/** View-projection of eye-relative coordinates (column-major), horizontal FOV. */
function viewProjection(cam, aspect) {
  const { forward: f, right: r, up: u } = basis(cam);
  const sx = 1 / Math.tan(rad(cam.fov) / 2);
  const sy = sx * aspect;
  const near = 5;
  const far = 400000;
  const a = (far + near) / (near - far);
  const b = (2 * far * near) / (near - far);
  // Rows of the view matrix: right, up, -forward; then a standard perspective.
  const m = new Float32Array(16);
  const rows = [
    [sx * r[0], sx * r[1], sx * r[2], 0],
    [sy * u[0], sy * u[1], sy * u[2], 0],
    [-a * f[0], -a * f[1], -a * f[2], b],
    [f[0], f[1], f[2], 0],
  ];
  for (let row = 0; row < 4; row++) for (let col = 0; col < 4; col++) m[col * 4 + row] = rows[row][col];
  return m;
}

/** Canvas pixel (CSS pixels, origin top-left) of world point p, or null when behind the eye. */
function project(p) {
  const cam = state.camera;
  const { forward, right, up } = basis(cam);
  const d = [p[0] - cam.x, p[1] - cam.y, p[2] - cam.z];
  const depth = dot(d, forward);
  if (depth <= 0) return null;
  const tanH = Math.tan(rad(cam.fov) / 2);
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  const tanV = (tanH * h) / w;
  const x = dot(d, right) / depth / tanH;
  const y = dot(d, up) / depth / tanV;
  return [((x + 1) / 2) * w, ((1 - y) / 2) * h];
}

// ---------------------------------------------------------------------------
// Tiles: which ones the camera needs, loading, dropping.
// ---------------------------------------------------------------------------

function drawnLayers() {
  return worldInfo.layers
    .map((l, i) => ({ ...l, index: i }))
    .filter((l) => !state.layers || state.layers.includes(l.name));
}

/**
 * The tiles the camera sees, as `cloudscape render` plans them (the client's
 * planTiles: scene.rs plan_bands, the view distance `view=` or the renderer's, the
 * shadows thrown by the loaded sky's sun, which is the tiles' sun bucket's centre;
 * straight down before the sky is in, and the plan grows once it is), coarsened until
 * at most MAX_TILES remain.
 */
function plan() {
  const sun = skyIsCurrent() ? skyInfo.sun.direction : null;
  const layers = drawnLayers().map((l) => l.name);
  const [w, h] = [canvas.clientWidth, canvas.clientHeight];
  for (let lod = LOD_PIXELS[state.quality]; ; lod *= 2) {
    const tiles = planTiles(worldInfo, state.camera, w, h, { lodPixels: lod, viewDistance: state.viewDistance, sun, layers, maxTiles: MAX_TILES });
    if (tiles && tiles.length <= MAX_TILES) {
      return tiles.map((t) => ({ layer: t.layerIndex, layerName: t.layer, z: t.z, x: t.x, y: t.y, origin: t.origin, size: t.size }));
    }
  }
}

/** The canonical frame time nearest `t`: what the server snaps sky.json's `t` to. */
function snapTime(t) {
  const period = Math.min(...worldInfo.layers.map((l) => l.frame_seconds));
  return Math.round(t / period) * period;
}

/** The parameters every tile of the current view shares, but for `t` (quality, sun): part of a tile's key. */
function generation() {
  let q = `quality=${state.quality}`;
  if (state.sun) q += `&sun=${state.sun[0]},${state.sun[1]}`;
  return q;
}

/** When and how the client asks for a tile: at `t`, in the view's quality and sun (none: the clock's). */
function tileTime(t) {
  return state.sun ? { t, quality: state.quality, sun: state.sun } : { t, quality: state.quality };
}

/** A planned tile as the client names it. */
const tileRef = (p) => ({ layer: p.layerName, z: p.z, x: p.x, y: p.y });

/**
 * Loaded or loading tiles by key (`gen|layer/z/x/y@t0`). A tile is `queued`, then
 * `loading`, `shading` (its billboards decoded, its ground shadow being derived),
 * `ready` (drawn) or `failed`.
 */
const tiles = new Map();
/** Keys the current plan wants. */
let wanted = [];
let queue = [];
/** Tiles whose next keyframe to fetch ahead of need when nothing else waits: { key, tile }. */
let prefetchQueue = [];
const prefetching = new Set();
let inFlight = 0;
let instancesDirty = true;

/** Tile products the viewer fetches besides the billboards: precipitation.png where the layer can rain or snow. */
function extraProducts(layer) {
  return state.weather && layer.precipitates ? ['precipitation.png'] : [];
}

/** An image's RGBA bytes (row 0 first), for reading values on the CPU. */
function pixelsOf(image) {
  const c = new OffscreenCanvas(image.width, image.height);
  const ctx = c.getContext('2d');
  ctx.drawImage(image, 0, 0);
  return ctx.getImageData(0, 0, image.width, image.height).data;
}

/**
 * A decoded keyframe's billboards as instance floats (centres relative to the tile
 * origin; t0 made relative to the buffer's time origin when drawn).
 */
function instanceData(k) {
  const { count, records: r, header } = k;
  const span = header.t0 !== null && header.t1 !== null ? header.t1 - header.t0 : 0;
  const data = new Float32Array(count * INSTANCE_FLOATS);
  for (let i = 0; i < count; i++) {
    const d = i * INSTANCE_FLOATS;
    data[d] = r.offset[3 * i];
    data[d + 1] = r.offset[3 * i + 1];
    data[d + 2] = r.offset[3 * i + 2];
    data[d + 3] = r.radius[i];
    data[d + 4] = r.velocity[2 * i];
    data[d + 5] = r.velocity[2 * i + 1];
    data[d + 7] = span;
    for (let c = 0; c < 3; c++) {
      data[d + 8 + c] = r.colour[6 * i + c];
      data[d + 11 + c] = r.colour[6 * i + 3 + c];
    }
    data[d + 14] = r.splatTau[2 * i];
    data[d + 15] = r.splatTau[2 * i + 1];
    data[d + 16] = r.tauSun[2 * i];
    data[d + 17] = r.tauSun[2 * i + 1];
  }
  return data;
}

/**
 * The rectangle of the layer's base, [x0, y0, x1, y1] in metres, that a keyframe's
 * balls can shadow at either end for the tile's own sun (null with the sun down): a
 * tile's shadow is cast only by tiles whose reach touches it.
 */
function shadowReach(k, base) {
  const s = keyframeSun(k);
  if (!(s[2] > 0) || !k.count) return null;
  const r = k.records;
  const o = k.header.origin;
  const span = k.header.t1 - k.header.t0 || 0;
  let maxR = 0;
  const box = [Infinity, Infinity, -Infinity, -Infinity];
  for (let b = 0; b < k.count; b++) {
    maxR = Math.max(maxR, r.radius[b]);
    const lift = (r.offset[3 * b + 2] - base) / s[2];
    for (let e = 0; e < 2; e++) {
      const x = o[0] + r.offset[3 * b] + r.velocity[2 * b] * span * e - s[0] * lift;
      const y = o[1] + r.offset[3 * b + 1] + r.velocity[2 * b + 1] * span * e - s[1] * lift;
      box[0] = Math.min(box[0], x);
      box[1] = Math.min(box[1], y);
      box[2] = Math.max(box[2], x);
      box[3] = Math.max(box[3], y);
    }
  }
  // The footprint of a ball reaches r / s_z from its centre's.
  const m = maxR / s[2];
  return [box[0] - m, box[1] - m, box[2] + m, box[3] + m];
}

async function loadTile(tile) {
  const layer = worldInfo.layers[tile.layer];
  const at = tileTime(tile.t0);
  const ref = tileRef(tile);
  const [decoded, rain] = await Promise.all([
    client.keyframe(worldInfo, ref, at),
    ...extraProducts(layer).map((p) => client.bytes(client.tilePath(worldInfo, ref, p, at))),
  ]);
  const rainImage = rain ? await decodeImage(rain, 'image/png') : null;
  return { decoded, rainImage };
}

function pump() {
  while (inFlight < MAX_IN_FLIGHT && queue.length) {
    const tile = queue.shift();
    if (!wanted.includes(tile.key)) {
      tiles.delete(tile.key);
      continue;
    }
    inFlight++;
    tile.state = 'loading';
    loadTile(tile)
      .then(({ decoded, rainImage }) => {
        if (!tiles.has(tile.key)) return;
        if (rainImage) {
          // precipitation.png (src/products/precipitation.rs): R rate, G snow at sea
          // level, B streak top, A precipitating; data, so linear and unpremultiplied.
          // A dry tile keeps neither: no box to march through, nothing at the eye.
          const pixels = pixelsOf(rainImage);
          let wet = false;
          for (let i = 3; i < pixels.length && !wet; i += 4) wet = pixels[i] > 0;
          if (wet) {
            tile.rain = texture(rainImage, gl.LINEAR);
            tile.rainPixels = pixels;
          }
          rainImage.close?.();
        }
        const base = worldInfo.layers[tile.layer].base;
        tile.billboards = decoded;
        tile.instances = instanceData(decoded);
        tile.held = { layer: tile.layer, base, keyframe: decoded };
        tile.reach = shadowReach(decoded, base);
        tile.sun = [decoded.header.sun.azimuthDeg, decoded.header.sun.elevationDeg];
        // The span the bytes say they cover (a version-1 tile: an instant).
        tile.t0 = decoded.header.t0 ?? tile.t0;
        tile.t1 = decoded.header.t1 ?? tile.t0;
        // Drawn once its ground shadow is derived (the tile it replaces stands in
        // until then); the shadows its balls reach are derived again.
        tile.state = 'shading';
        queueShadow(tile);
        shadowsTouchedBy(tile);
      })
      .catch((e) => {
        viewerStats.failures++;
        tile.state = 'failed';
        showError(e.message);
      })
      .finally(() => {
        inFlight--;
        pump();
      });
  }
  // Ahead of need, when the view's own tiles are all asked for; one request stays free
  // for a tile the view needs next.
  while (inFlight < MAX_IN_FLIGHT - 1 && !queue.length && prefetchQueue.length) {
    const { key, tile } = prefetchQueue.shift();
    if (prefetching.has(key)) continue;
    inFlight++;
    prefetching.add(key);
    const products = ['billboards.bin', ...extraProducts(worldInfo.layers[tile.layer])];
    // Errors are the client's to swallow: the tile is asked for again when its keyframe comes.
    client.prefetchNext(worldInfo, tileRef(tile), tileTime(state.t), products).finally(() => {
      prefetching.delete(key);
      inFlight--;
      pump();
    });
  }
}

/** Whether the client holds everything of a planned tile's keyframe `t0` (prefetched). */
function holdsKeyframe(p, t0) {
  const ref = tileRef(p);
  const at = tileTime(t0);
  return (
    client.keyframes.get(client.variant(worldInfo, ref, at), t0) !== null &&
    extraProducts(worldInfo.layers[p.layer]).every((product) => client.holds(client.tilePath(worldInfo, ref, product, at)))
  );
}

/**
 * Re-plans, queues the new tiles (each at the keyframe that holds `state.t`), queues
 * the next keyframe of tiles past their prefetch point, and drops the tiles no longer
 * needed.
 */
function updateTiles() {
  if (!worldInfo) return;
  loadSky().catch((e) => {
    viewerStats.failures++;
    showError(e.message);
  });
  loadLightning().catch((e) => {
    viewerStats.failures++;
    showError(e.message);
  });
  const gen = generation();
  const planned = plan();
  const next = [];
  wanted = planned.map((p) => {
    const k = keyframeOf(worldInfo.layers[p.layer], p.z, state.t, worldInfo.max_time);
    const key = `${gen}|${p.layerName}/${p.z}/${p.x}/${p.y}@${k.t0}`;
    if (!tiles.has(key)) {
      const tile = { ...p, key, gen, t0: k.t0, t1: k.t1, state: 'queued' };
      tiles.set(key, tile);
      queue.push(tile);
    }
    if (k.span > 0 && k.f >= prefetchAt(p.z, p.x, p.y) && !holdsKeyframe(p, k.t1)) {
      next.push({ key: `${gen}|${p.layerName}/${p.z}/${p.x}/${p.y}@${k.t1}`, tile: p });
    }
    return key;
  });
  prefetchQueue = next.filter((n) => !prefetching.has(n.key));
  // Nearest first.
  const cam = state.camera;
  const centreDistance = (t) => Math.hypot(t.origin[0] + t.size / 2 - cam.x, t.origin[1] + t.size / 2 - cam.y);
  queue.sort((a, b) => centreDistance(a) - centreDistance(b));
  dropUnneeded();
  pump();
}

/** Drops tiles that are neither wanted nor standing in for a wanted tile still loading. */
function dropUnneeded() {
  const missing = wanted.map((k) => tiles.get(k)).filter((t) => t && t.state !== 'ready');
  for (const [key, tile] of tiles) {
    if (wanted.includes(key)) continue;
    const standsIn =
      tile.state === 'ready' &&
      missing.some(
        (m) =>
          m.layer === tile.layer &&
          m.origin[0] < tile.origin[0] + tile.size &&
          tile.origin[0] < m.origin[0] + m.size &&
          m.origin[1] < tile.origin[1] + tile.size &&
          tile.origin[1] < m.origin[1] + m.size,
      );
    if (!standsIn) dropTile(key);
  }
}

function dropTile(key) {
  const tile = tiles.get(key);
  if (!tile) return;
  if (tile.shadow) gl.deleteTexture(tile.shadow);
  if (tile.rain) gl.deleteTexture(tile.rain);
  tiles.delete(key);
  shadowJobs.delete(key);
  queue = queue.filter((t) => t.key !== key);
  // The shadows it was cast into lose its balls.
  for (const k of wanted) {
    const t = tiles.get(k);
    if (t && t.shadowSources && t.shadowSources.includes(key)) queueShadow(t);
  }
  instancesDirty = true;
}

function drawnTiles() {
  return [...tiles.values()].filter((t) => t.state === 'ready');
}

// ---------------------------------------------------------------------------
// Ground shadows, derived from the billboards of the layer's tiles.
// ---------------------------------------------------------------------------

/** Shadow derivations waiting or under way, by tile key: { tile, derivation, sources, at, from }. */
const shadowJobs = new Map();

const tileRect = (t) => [t.origin[0], t.origin[1], t.origin[0] + t.size, t.origin[1] + t.size];
const overlaps = (a, b) => Boolean(a && b) && a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3];

/** The loaded tiles whose balls may shadow `tile`: those of its layer the plan wants whose reach touches it. */
function shadowSources(tile) {
  const rect = tileRect(tile);
  const out = [];
  for (const k of wanted) {
    const s = tiles.get(k);
    if (s && s.billboards && s.layer === tile.layer && overlaps(s.reach, rect)) out.push(s);
  }
  if (!out.includes(tile)) out.push(tile);
  return out;
}

/** (Re)starts the derivation of `tile`'s shadow maps; it keeps drawing its last ones meanwhile. */
function queueShadow(tile) {
  shadowJobs.set(tile.key, { tile, derivation: null, sources: null, at: 0, from: 0 });
}

/** `changed` loaded: the wanted tiles of its layer whose shadow its balls reach are derived again. */
function shadowsTouchedBy(changed) {
  for (const k of wanted) {
    const t = tiles.get(k);
    if (t && t !== changed && t.billboards && t.layer === changed.layer && overlaps(changed.reach, tileRect(t))) queueShadow(t);
  }
}

/**
 * Works on the queued derivations for about `budget` ms (at least one step of
 * SHADOW_STEP balls): tiles waiting to be drawn first, then the nearest.
 */
function deriveShadows(budget) {
  if (!shadowJobs.size) return;
  const started = performance.now();
  const cam = state.camera;
  const distance = (t) => Math.hypot(t.origin[0] + t.size / 2 - cam.x, t.origin[1] + t.size / 2 - cam.y);
  const jobs = [...shadowJobs.values()].sort(
    (a, b) => (a.tile.state === 'shading' ? 0 : 1) - (b.tile.state === 'shading' ? 0 : 1) || distance(a.tile) - distance(b.tile),
  );
  let spent = false;
  for (const job of jobs) {
    const t = job.tile;
    if (!job.derivation) {
      job.derivation = new ShadowDerivation(t.held);
      job.sources = shadowSources(t);
    }
    while (job.at < job.sources.length && !spent) {
      const s = job.sources[job.at];
      const to = Math.min(job.from + SHADOW_STEP, s.billboards.count);
      job.derivation.add(s.held, job.from, to);
      if (to >= s.billboards.count) {
        job.at++;
        job.from = 0;
      } else {
        job.from = to;
      }
      spent = performance.now() - started > budget;
    }
    if (job.at < job.sources.length) break;
    if (shadowJobs.get(t.key) === job) {
      shadowJobs.delete(t.key);
      finishShadow(t, job.derivation.finish(), job.sources.map((s) => s.key));
    }
    if (spent) break;
  }
  viewerStats.shadowMs += performance.now() - started;
}

/** Uploads a tile's derived maps as its RG shadow texture (R at t0, G at t1) and draws it. */
function finishShadow(tile, maps, sources) {
  const n = TILE_COLUMNS;
  const data = new Float32Array(2 * n * n);
  let m0 = 0;
  let m1 = 0;
  for (let i = 0; i < n * n; i++) {
    data[2 * i] = maps.t0[i];
    data[2 * i + 1] = maps.t1[i];
    m0 += maps.t0[i];
    m1 += maps.t1[i];
  }
  if (!tile.shadow) {
    tile.shadow = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tile.shadow);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RG16F, n, n);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  } else {
    gl.bindTexture(gl.TEXTURE_2D, tile.shadow);
  }
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
  gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, n, n, gl.RG, gl.FLOAT, data);
  tile.meanShadow = [m0 / (n * n), m1 / (n * n)];
  tile.shadowMaps = maps;
  tile.shadowSources = sources;
  viewerStats.shadows++;
  // The tile's maps light the layers below it too.
  instancesDirty = true;
  if (tile.state === 'shading') {
    tile.state = 'ready';
    dropUnneeded();
  }
  // A new picture, though nothing else changed.
  lastDrawn = '';
  lastDrawnStill = '';
}

// ---------------------------------------------------------------------------
// Drawing.
// ---------------------------------------------------------------------------

/**
 * All drawn instances, centres relative to `bufferOrigin` and keyframe times relative
 * to `timeOrigin` (so f32 holds them at any world position and clock), and a sorted
 * copy for the GPU.
 */
let instances = new Float32Array(0);
let sorted = new Float32Array(0);
let bufferOrigin = [0, 0];
let timeOrigin = 0;
let lastSortEye = null;
let lastSortTime = null;
let lastSortAt = 0;

function rebuildInstances() {
  const drawn = drawnTiles();
  const total = drawn.reduce((n, t) => n + t.billboards.count, 0);
  instances = new Float32Array(total * INSTANCE_FLOATS);
  sorted = new Float32Array(total * INSTANCE_FLOATS);
  bufferOrigin = [Math.round(state.camera.x), Math.round(state.camera.y)];
  timeOrigin = Math.floor(state.t);
  let at = 0;
  // The layers above light each tile's billboards (the client's lightBeneathLayers,
  // view/held.rs beneath_layers): through the drawn tiles of the other layers whose
  // ground shadow maps are derived.
  const shadowed = drawn.filter((t) => t.shadowMaps).map((t) => ({ ...t.held, maps: t.shadowMaps }));
  for (const t of drawn) {
    const { count, header } = t.billboards;
    const data = t.instances;
    instances.set(data, at);
    const lit = lightBeneathLayers(t.held, shadowed);
    for (let i = 0; i < count; i++) {
      const d = at + i * INSTANCE_FLOATS;
      for (let c = 0; c < 3; c++) {
        instances[d + 8 + c] = lit.colour[6 * i + c];
        instances[d + 11 + c] = lit.colour[6 * i + 3 + c];
      }
      instances[d + 16] = lit.tauSun[2 * i];
      instances[d + 17] = lit.tauSun[2 * i + 1];
    }
    const ox = header.origin[0] - bufferOrigin[0];
    const oy = header.origin[1] - bufferOrigin[1];
    const ot = t.t0 - timeOrigin;
    for (let i = 0; i < count; i++) {
      instances[at + i * INSTANCE_FLOATS] += ox;
      instances[at + i * INSTANCE_FLOATS + 1] += oy;
      instances[at + i * INSTANCE_FLOATS + 6] = ot;
    }
    at += data.length;
  }
  viewerStats.billboards = total;
  instancesDirty = false;
  lastSortEye = null;
}

/** Sorts instances back to front from the eye, where they are at `time` (relative to timeOrigin), and uploads them. */
function sortInstances(eye, time) {
  const n = instances.length / INSTANCE_FLOATS;
  const dist = new Float64Array(n);
  const order = new Uint32Array(n);
  for (let i = 0; i < n; i++) {
    const o = i * INSTANCE_FLOATS;
    const since = clamp(time - instances[o + 6], 0, instances[o + 7]);
    const dx = instances[o] + instances[o + 4] * since - eye[0];
    const dy = instances[o + 1] + instances[o + 5] * since - eye[1];
    const dz = instances[o + 2] - eye[2];
    dist[i] = dx * dx + dy * dy + dz * dz;
    order[i] = i;
  }
  order.sort((a, b) => dist[b] - dist[a]);
  for (let i = 0; i < n; i++) {
    sorted.set(instances.subarray(order[i] * INSTANCE_FLOATS, (order[i] + 1) * INSTANCE_FLOATS), i * INSTANCE_FLOATS);
  }
  gl.bindBuffer(gl.ARRAY_BUFFER, instanceBuffer);
  gl.bufferData(gl.ARRAY_BUFFER, sorted, gl.DYNAMIC_DRAW);
  lastSortEye = eye;
  lastSortTime = time;
  lastSortAt = performance.now();
}

/**
 * The shading parameters of the drawn tiles: a version-2 header's lighting, else
 * (version 1) ShadingParams::default(); and the sun's radiance, the header's, else
 * the sky's.
 */
function shading() {
  const t = drawnTiles().find((t) => t.billboards.header.lighting);
  if (!t) return { albedo: SHADING.albedo, phase: [SHADING.g1, SHADING.g2, SHADING.mix], octaves: SHADING.octaves, sunRgb: null };
  const l = t.billboards.header.lighting;
  const o = l.octaves;
  return { albedo: l.albedo, phase: [l.phase.g1, l.phase.g2, l.phase.mix], octaves: [o.count, o.a, o.b, o.c], sunRgb: l.sunRgb };
}

/** The sun drawn: the manual one, else the one the server shaded the tiles for. */
function currentSun() {
  if (state.sun) return state.sun;
  const t = drawnTiles().find((t) => t.sun);
  return t ? t.sun : [180, 45];
}

function resize() {
  const dpr = Math.min(window.devicePixelRatio || 1, 2);
  const w = Math.max(1, Math.round(canvas.clientWidth * dpr));
  const h = Math.max(1, Math.round(canvas.clientHeight * dpr));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
}

// ---------------------------------------------------------------------------
// Weather: precipitation at the eye, lightning strikes and their flashes.
// ---------------------------------------------------------------------------

/**
 * Rain or snow where the eye is: the heaviest rate of the drawn precipitation maps
 * whose column holds the eye below its streak top (the finest tile of each layer),
 * and that column's streak top (altitude, m).
 */
function eyePrecipitation() {
  const cam = state.camera;
  let rate = 0;
  let snow = false;
  let streakTop = 0;
  const finest = new Map();
  for (const t of drawnTiles()) {
    if (!t.rainPixels) continue;
    const u = (cam.x - t.origin[0]) / t.size;
    const v = (cam.y - t.origin[1]) / t.size;
    if (u < 0 || u >= 1 || v < 0 || v >= 1) continue;
    const f = finest.get(t.layer);
    if (!f || t.z < f.z) finest.set(t.layer, t);
  }
  for (const t of finest.values()) {
    const u = (cam.x - t.origin[0]) / t.size;
    const v = (cam.y - t.origin[1]) / t.size;
    const col = Math.min(255, Math.floor(u * 256));
    const row = Math.min(255, 255 - Math.floor(v * 256)); // row 0 is the northern edge
    const i = (row * 256 + col) * 4;
    const p = t.rainPixels;
    if (p[i + 3] === 0) continue;
    const l = worldInfo.layers[t.layer];
    const top = l.base + (p[i + 2] / 255) * (l.top - l.base);
    if (cam.z > top) continue;
    const r = 100 * (p[i] / 255) ** 2;
    if (r > rate) {
      rate = r;
      snow = cam.z >= worldInfo.snow_level;
      streakTop = top;
    }
  }
  return { rate, snow, top: streakTop };
}

/** Strikes around the view (the last /lightning answer), sorted by time. */
let strikes = [];
let strikesKey = '';
let strikesLoading = '';
/** Flashes on screen: { strike, start (performance.now()) }. */
let flashes = [];
let lastStrikeT = null;

/** Asks /lightning for the strikes of the current window around the eye, when the world has lightning. */
async function loadLightning() {
  if (!state.weather || !worldInfo.layers.some((l) => l.lightning)) {
    strikes = [];
    stats.strikes = 0;
    return;
  }
  const w0 = Math.floor(state.t / LIGHTNING_WINDOW) * LIGHTNING_WINDOW;
  const cx = Math.round(state.camera.x / 10000) * 10000;
  const cy = Math.round(state.camera.y / 10000) * 10000;
  const key = `${state.world}|${w0}|${cx}|${cy}`;
  if (key === strikesKey || key === strikesLoading) return;
  strikesLoading = key;
  const h = LIGHTNING_HALF_SIDE;
  const bbox = [cx - h, cy - h, cx + h, cy + h].join(',');
  try {
    const answer = await client.json(
      `/v1/worlds/${encodeURIComponent(state.world)}/lightning?bbox=${bbox}&t0=${w0}&t1=${w0 + LIGHTNING_WINDOW}`,
    );
    if (strikesLoading !== key) return;
    strikes = answer.strikes.slice().sort((a, b) => a.t - b.t);
    strikesKey = key;
    stats.strikes = strikes.length;
  } finally {
    if (strikesLoading === key) strikesLoading = '';
  }
}

/** Starts the flash of `strike` (a /lightning strike); `hold` keeps it at its brightest (tests, screenshots). */
function flash(strike, hold = false) {
  flashes.push({ strike, start: performance.now(), hold });
  stats.flashes++;
}

/** Flashes the strikes the drawn time passed since the last frame (not on a jump). */
function strikesPassed() {
  const t = state.t;
  if (lastStrikeT !== null && t > lastStrikeT && t - lastStrikeT <= FLASH_MAX_JUMP) {
    for (const s of strikes) if (s.t > lastStrikeT && s.t <= t) flash(s);
  }
  lastStrikeT = t;
  const now = performance.now();
  flashes = flashes.filter((f) => f.hold || now - f.start < FLASH_MS);
}

/** A flash's brightness at `ms` after it started: a stroke, then a return stroke. */
function flashGain(ms) {
  const first = Math.exp(-ms / 60);
  const second = ms > 140 ? 0.7 * Math.exp(-(ms - 140) / 70) : 0;
  return first + second;
}

/** A jagged bolt from the cloud base down to the strike point, relative to the eye. */
function boltPoints(strike, cam) {
  const l = worldInfo.layers.find((l) => l.lightning) || worldInfo.layers[0];
  const n = 24;
  const pts = new Float32Array((n + 1) * 3);
  // A deterministic walk from the strike's own numbers: the same bolt every time.
  let seed = Math.abs(Math.floor(strike.x * 7 + strike.y * 13 + strike.t * 101)) % 2147483647 || 1;
  const rnd = () => (seed = (seed * 48271) % 2147483647) / 2147483647 - 0.5;
  let dx = 0;
  let dy = 0;
  for (let i = 0; i <= n; i++) {
    const z = l.base * (1 - i / n);
    pts.set([strike.x + dx - cam.x, strike.y + dy - cam.y, z - cam.z], i * 3);
    dx += rnd() * 0.12 * (l.base / n) * 3;
    dy += rnd() * 0.12 * (l.base / n) * 3;
  }
  return pts;
}

/**
 * The lit haze colour of rain and snow: grey, the brightness of the sky above less
 * what the storm's clouds take (drops scatter all colours alike), and a little sun.
 */
function hazeRgb(light) {
  const grey = (c) => 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
  const v = 0.45 * grey(light.above) + 0.05 * grey(light.sunGround) * Math.max(light.dir[2], 0);
  return [v, v, v * 1.03];
}

/** Sets the ATMOSPHERE and GROUND uniforms of `prog` from skyInfo (sky table on texture unit 1). */
function setAtmosphere(prog) {
  const u = prog.u;
  const v = skyValues;
  gl.activeTexture(gl.TEXTURE1);
  gl.bindTexture(gl.TEXTURE_2D, skyTexture);
  gl.uniform1i(u.skyTable, 1);
  gl.uniform2fv(u.skySize, v.skySize);
  gl.uniform3fv(u.sunDir, v.sunDir);
  gl.uniform3fv(u.night, v.night);
  gl.uniform3fv(u.betaR, v.betaR);
  gl.uniform4fv(u.mie, v.mie);
  gl.uniform4fv(u.air, v.air);
  gl.uniform3fv(u['sunT[0]'], v.sunT);
  gl.uniform3fv(u['multi[0]'], v.multi);
  if (u.sunGround) {
    gl.uniform3fv(u.sunGround, v.sunGround);
    gl.uniform3fv(u.above, v.above);
    gl.uniform3fv(u.groundAlbedo, v.groundAlbedo);
  }
  gl.activeTexture(gl.TEXTURE0);
}

/**
 * The sky wanted: the manual sun's; else that of the sun bucket the drawn tiles were
 * shaded for (their header's: the sky changes with the tiles, only when the clock's
 * sun moves into another bucket); else, before any tile is drawn, the clock's sun at
 * the drawn time, which the tiles' sun then matches (the same bucket, not asked for
 * again).
 */
function wantedSky() {
  if (state.sun) return { url: `/v1/sky.json?sun=${state.sun[0]},${state.sun[1]}` };
  const t = drawnTiles().find((t) => t.sun);
  if (t) return { url: `/v1/sky.json?sun=${t.sun[0]},${t.sun[1]}`, sun: t.sun };
  return { url: `/v1/sky.json?t=${snapTime(state.t)}`, t: state.t };
}

/**
 * What the loaded sky was asked for: its URL and, for the clock's sun, the drawn time.
 * Without tiles a clock sky stands for 10 minutes of world time (a sun bucket spans
 * several degrees), so a clock that runs does not ask for a sky every frame.
 */
let skyLoaded = null;

/** Whether the loaded sky is the wanted one. */
function skyIsCurrent(w = wantedSky()) {
  if (!skyInfo || !skyLoaded) return false;
  if (w.url === skyLoaded.url) return true;
  const near = (a, b) => Math.abs(a - b) < 1e-3;
  if (w.sun) return near(skyInfo.sun.azimuth_deg, w.sun[0]) && near(skyInfo.sun.elevation_deg, w.sun[1]);
  if (w.t !== undefined) return skyLoaded.t !== undefined && Math.abs(w.t - skyLoaded.t) < 600;
  return false;
}

/** Loads the sky of the current sun when it changed. */
async function loadSky() {
  const w = wantedSky();
  if (skyIsCurrent(w) || w.url === skyUrlLoading) return;
  skyUrlLoading = w.url;
  let info;
  try {
    info = await client.json(w.url);
  } finally {
    skyUrlLoading = '';
  }
  const { table, values } = skyUniforms(info);
  const { data, columns, rows } = table;
  if (skyTexture) gl.deleteTexture(skyTexture);
  skyTexture = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, skyTexture);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA16F, columns, rows, 0, gl.RGBA, gl.FLOAT, data);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  skyInfo = info;
  skyValues = values;
  skyLoaded = { url: w.url, t: w.t };
  // The wanted sky may have moved on while this one loaded; else the plan follows its
  // sun (the tiles whose shadows it throws into view).
  if (!skyIsCurrent()) loadSky().catch((e) => showError(e.message));
  else if (worldInfo) updateTiles();
}

/** Sets TONE's uniforms of `prog`: sky.json's exposure, and whether the pass maps its own output. */
function setDisplay(prog, toneOut) {
  gl.uniform1f(prog.u.exposure ?? null, skyValues.exposure);
  gl.uniform1i(prog.u.toneOut ?? null, toneOut ? 1 : 0);
}

/**
 * The mean shadow of the drawn tiles (scene::mean_shadow): over each layer's tiles
 * the mean of their maps at the drawn time, multiplied over the layers.
 */
function meanShadow(drawn) {
  const layers = new Map();
  for (const t of drawn) {
    const f = fraction(t.t0, t.t1, state.t);
    const m = clamp((1 - f) * t.meanShadow[0] + f * t.meanShadow[1], 0, 1);
    const e = layers.get(t.layer) || { sum: 0, n: 0 };
    layers.set(t.layer, { sum: e.sum + (Number.isFinite(m) ? m : 1), n: e.n + 1 });
  }
  let far = 1;
  for (const e of layers.values()) far *= e.sum / e.n;
  return far;
}

/**
 * Draws a frame as view::held::draw does: the ground shadows, the sky and the shadowed
 * ground, the billboards over them; in linear radiance into the scene target, mapped
 * for display at the end. Rain, bolts, streaks and flashes are the viewer's own.
 */
function draw() {
  resize();
  if (instancesDirty) rebuildInstances();
  const cam = state.camera;
  const [w, h] = [canvas.width, canvas.height];
  const aspect = w / h;
  const { forward, right, up } = basis(cam);
  const light = lighting();
  const vp = viewProjection(cam, aspect);
  const tanH = Math.tan(rad(cam.fov) / 2);
  let calls = 0;
  // Without float targets every pass maps its own output onto the canvas.
  const scene = floatTargets ? offscreen('scene', w, h, [RGBA16F()]) : null;
  const toneOut = !scene;
  stats.linear = Boolean(scene);

  gl.viewport(0, 0, w, h);
  gl.disable(gl.DEPTH_TEST);
  gl.disable(gl.CULL_FACE);

  // Ground shadows: each tile's quad on the ground multiplies its shadow into the
  // shadow target, cleared to 1 (no shadow where no tile's falls). A tile's maps are
  // indexed where the sun ray from the ground crosses the layer's base: the quad is
  // shifted away from the tile's sun by (s_x, s_y) · base / s_z (shadowShift,
  // render::tile::shadow_shift).
  const drawn = drawnTiles();
  const shadowFormat = floatTargets ? [gl.R16F, gl.RED, gl.HALF_FLOAT] : [gl.RGBA8, gl.RGBA, gl.UNSIGNED_BYTE];
  const shadows = cam.z > 0 && light.dir[2] > 0 ? offscreen('shadow', w, h, [shadowFormat]) : null;
  const far = meanShadow(drawn);
  if (shadows) {
    gl.bindFramebuffer(gl.FRAMEBUFFER, shadows.fb);
    gl.clearColor(1, 1, 1, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.DST_COLOR, gl.ZERO);
    gl.useProgram(shadowProgram.program);
    const hu = shadowProgram.u;
    gl.uniformMatrix4fv(hu.viewProj, false, vp);
    gl.activeTexture(gl.TEXTURE0);
    gl.uniform1i(hu.shadow, 0);
    gl.bindVertexArray(emptyVao);
    for (const t of drawn) {
      const shift = shadowShift(t.billboards, worldInfo.layers[t.layer].base);
      gl.uniform1f(hu.shadowF, fraction(t.t0, t.t1, state.t));
      gl.bindTexture(gl.TEXTURE_2D, t.shadow);
      gl.uniform4f(hu.rect, t.origin[0] - shift[0] - cam.x, t.origin[1] - shift[1] - cam.y, t.size, cam.z);
      gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
      calls++;
    }
  }

  // Sky and ground.
  gl.bindFramebuffer(gl.FRAMEBUFFER, scene ? scene.fb : null);
  gl.disable(gl.BLEND);
  gl.useProgram(skyProgram.program);
  const su = skyProgram.u;
  gl.uniform3fv(su.forward, forward);
  gl.uniform3fv(su.right, right);
  gl.uniform3fv(su.up, up);
  gl.uniform2f(su.tanHalf, tanH, tanH / aspect);
  setAtmosphere(skyProgram);
  setDisplay(skyProgram, toneOut);
  gl.uniform3fv(su.sunRgb, light.sunRgb);
  gl.uniform2f(su.disc, skyInfo.sun_disc.angular_radius, skyInfo.sun_disc.gain);
  gl.uniform1f(su.eyeZ, cam.z);
  gl.uniform1i(su.shadows, shadows ? 1 : 0);
  gl.uniform1f(su.far, far);
  gl.uniform1f(su.viewDistance, state.viewDistance);
  gl.activeTexture(gl.TEXTURE2);
  gl.bindTexture(gl.TEXTURE_2D, shadows ? shadows.textures[0] : null);
  gl.uniform1i(su.shadowTex, 2);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindVertexArray(emptyVao);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
  calls++;

  // Rain and snow under the clouds, hazing the sky and the ground by their distance:
  // before the billboards (clouds in front of a distant shaft hide it). When the eye
  // stands in it, each billboard takes the rain in front of it (billboardProgram).
  const wet = drawn.filter((t) => t.rain);
  stats.precipitationTiles = wet.length;
  const haze = hazeRgb(light);
  const atEye = eyePrecipitation();
  if (wet.length) {
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(rainProgram.program);
    const ru = rainProgram.u;
    gl.uniformMatrix4fv(ru.viewProj, false, vp);
    gl.uniform1f(ru.eyeZ, cam.z);
    gl.uniform1f(ru.snowLevel, worldInfo.snow_level);
    gl.uniform1f(ru.viewDistance, state.viewDistance);
    gl.uniform3fv(ru.hazeRgb, haze);
    setDisplay(rainProgram, toneOut);
    gl.activeTexture(gl.TEXTURE0);
    gl.uniform1i(ru.rain, 0);
    gl.bindVertexArray(emptyVao);
    for (const t of wet) {
      const l = worldInfo.layers[t.layer];
      gl.uniform3f(ru.boxMin, t.origin[0] - cam.x, t.origin[1] - cam.y, -cam.z);
      gl.uniform3f(ru.boxSize, t.size, t.size, l.top);
      gl.uniform1f(ru.layerBase, l.base);
      gl.uniform1f(ru.layerThickness, l.top - l.base);
      gl.bindTexture(gl.TEXTURE_2D, t.rain);
      gl.drawArrays(gl.TRIANGLES, 0, 36);
      calls++;
    }
  }

  // Lightning: the bolts of cloud-to-ground flashes; the brightest flash lights the
  // clouds around it, and every flash the air (the veil, last).
  const now = performance.now();
  let veil = 0;
  let brightest = null;
  for (const f of flashes) {
    const g = f.hold ? 1 : flashGain(now - f.start);
    const s = f.strike;
    const d = Math.hypot(s.x - cam.x, s.y - cam.y, s.z - cam.z);
    veil += 0.35 * g * Math.exp(-d / 15000);
    if (!brightest || g > brightest.gain) brightest = { strike: s, gain: g };
    if (s.kind === 'cg' && g > 0.05) {
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.ONE, gl.ONE);
      gl.useProgram(boltProgram.program);
      gl.uniformMatrix4fv(boltProgram.u.viewProj, false, vp);
      setDisplay(boltProgram, toneOut);
      gl.uniform1f(boltProgram.u.gain, Math.min(1, 1.5 * g));
      gl.bindVertexArray(boltVao);
      gl.bindBuffer(gl.ARRAY_BUFFER, boltBuffer);
      gl.bufferData(gl.ARRAY_BUFFER, boltPoints(s, cam), gl.DYNAMIC_DRAW);
      gl.drawArrays(gl.LINE_STRIP, 0, 25);
      gl.bindVertexArray(null);
      calls++;
    }
  }

  // Billboards, back to front.
  const n = instances.length / INSTANCE_FLOATS;
  if (n > 0) {
    const eye = [cam.x - bufferOrigin[0], cam.y - bufferOrigin[1], cam.z];
    const time = state.t - timeOrigin;
    // The clouds drift a few metres a second: while only the time runs, the order is
    // sorted again a few times a second, not every frame.
    if (
      !lastSortEye ||
      Math.hypot(eye[0] - lastSortEye[0], eye[1] - lastSortEye[1], eye[2] - lastSortEye[2]) > 1 ||
      (time !== lastSortTime && performance.now() - lastSortAt > RESORT_MS)
    ) {
      sortInstances(eye, time);
    }
    // Into the offscreen targets (cleared to nothing) when the erosion pass runs.
    const clouds = scene && SHADING.detailErosion > 0 ? offscreen('clouds', w, h, [RGBA16F(), RGBA16F()]) : null;
    if (clouds) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, clouds.fb);
      gl.clearColor(0, 0, 0, 0);
      gl.clear(gl.COLOR_BUFFER_BIT);
    }
    stats.erosion = Boolean(clouds);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(billboardProgram.program);
    const bu = billboardProgram.u;
    gl.uniformMatrix4fv(bu.viewProj, false, vp);
    gl.uniform3fv(bu.eye, eye);
    gl.uniform3fv(bu.forward, forward);
    gl.uniform3fv(bu.right, right);
    gl.uniform3fv(bu.up, up);
    gl.uniform2f(bu.tanHalf, tanH, tanH / aspect);
    gl.uniform2f(bu.viewport, w, h);
    setAtmosphere(billboardProgram);
    setDisplay(billboardProgram, toneOut);
    const sh = shading();
    gl.uniform3fv(bu.sunRgb, sh.sunRgb || light.sunRgb);
    gl.uniform1f(bu.albedo, sh.albedo);
    gl.uniform3fv(bu.phase, sh.phase);
    gl.uniform4fv(bu.octaves, sh.octaves);
    gl.uniform1f(bu.time, time);
    const wrap = (v) => v - 65536 * Math.floor(v / 65536);
    gl.uniform3f(bu.eyeMod, wrap(cam.x), wrap(cam.y), cam.z);
    gl.uniform1f(bu.pixelAngle, (2 * tanH) / w);
    gl.uniform1i(bu.detail, clouds ? 1 : 0);
    gl.uniform1f(bu.rainSigma, atEye.rate > 0 ? precipitationPerMetre(atEye.rate, atEye.snow) : 0);
    gl.uniform1f(bu.rainTop, atEye.top);
    gl.uniform3fv(bu.rainHaze, haze);
    if (brightest) {
      // A cloud-to-ground stroke lights the cloud base above it; an intra-cloud one, its own height.
      const s = brightest.strike;
      const lz = s.kind === 'cg' ? (worldInfo.layers.find((l) => l.lightning) || worldInfo.layers[0]).base + 500 : s.z;
      gl.uniform4f(bu.flashAt, s.x - cam.x, s.y - cam.y, lz - cam.z, brightest.gain);
    } else {
      gl.uniform4f(bu.flashAt, 0, 0, 0, 0);
    }
    gl.bindVertexArray(billboardVao);
    gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, n);
    calls++;
    gl.bindVertexArray(null);
    if (clouds) {
      // Erode the accumulated opacity and lay the clouds over the sky and ground.
      gl.bindFramebuffer(gl.FRAMEBUFFER, scene.fb);
      gl.useProgram(erosionProgram.program);
      const eu = erosionProgram.u;
      clouds.textures.forEach((t, i) => {
        gl.activeTexture(gl.TEXTURE0 + i);
        gl.bindTexture(gl.TEXTURE_2D, t);
      });
      gl.uniform1i(eu.cloud, 0);
      gl.uniform1i(eu.detailTex, 1);
      gl.uniform1f(eu.strength, SHADING.detailErosion);
      gl.bindVertexArray(emptyVao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      calls++;
      gl.activeTexture(gl.TEXTURE0);
    }
  }
  // The linear picture mapped for display.
  if (scene) {
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.disable(gl.BLEND);
    gl.useProgram(toneProgram.program);
    setDisplay(toneProgram, true);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, scene.textures[0]);
    gl.uniform1i(toneProgram.u.scene, 0);
    gl.bindVertexArray(emptyVao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    calls++;
  }
  // Streaks where the eye stands in rain or snow, then the flashes' veil.
  stats.eyeRate = atEye.rate;
  stats.eyeSnow = atEye.snow;
  if (atEye.rate > 0) {
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(streakProgram.program);
    const zu = streakProgram.u;
    gl.uniform2f(zu.viewport, canvas.width, canvas.height);
    gl.uniform1f(zu.time, (now / 1000) % 1000);
    gl.uniform1f(zu.rate, atEye.rate);
    gl.uniform1f(zu.snow, atEye.snow ? 1 : 0);
    gl.uniform3fv(zu.hazeRgb, haze);
    setDisplay(streakProgram, true);
    gl.bindVertexArray(emptyVao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    calls++;
  }
  if (veil > 0.002) {
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE);
    gl.useProgram(veilProgram.program);
    gl.uniform3f(veilProgram.u.rgb, 0.85 * veil, 0.9 * veil, veil);
    gl.bindVertexArray(emptyVao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    calls++;
  }
  stats.drawCalls = calls;
}

// ---------------------------------------------------------------------------
// Controls.
// ---------------------------------------------------------------------------

const $ = (id) => document.getElementById(id);
const keys = new Set();
let speed = 150; // m/s

function showError(message) {
  const el = $('error');
  el.textContent = message;
  el.hidden = false;
}

function syncUrl() {
  const c = state.camera;
  const p = new URLSearchParams();
  p.set('world', state.world);
  // Following the clock, the URL names no time: a reload follows it too.
  if (!state.follow) p.set('t', String(state.t));
  if (state.rate !== null) p.set('rate', String(state.rate));
  p.set('camera', [c.x, c.y, c.z, c.yaw, c.pitch, c.fov].map((v) => Math.round(v * 10) / 10).join(','));
  p.set('quality', state.quality);
  if (state.sun) p.set('sun', state.sun.join(','));
  if (state.layers) p.set('layers', state.layers.join(','));
  if (query.has('view')) p.set('view', String(state.viewDistance));
  if (!state.weather) p.set('weather', 'off');
  history.replaceState(null, '', `?${p}`);
}

function formatTime(t) {
  const day = Math.floor(t / 86400);
  const s = t - day * 86400;
  const hh = String(Math.floor(s / 3600)).padStart(2, '0');
  const mm = String(Math.floor((s % 3600) / 60)).padStart(2, '0');
  return `day ${day} ${hh}:${mm} (t = ${Math.round(t * 10) / 10} s)`;
}

function setTime(t) {
  state.t = clamp(t, 0, worldInfo ? worldInfo.max_time : 1e12);
  const slider = $('time');
  // The slider spans the two days from the start of the drawn time's day.
  const day = Math.floor(state.t / 86400) * 86400;
  if (Number(slider.min) !== day) {
    slider.min = String(day);
    slider.max = String(day + 172800);
  }
  slider.value = String(state.t);
  $('time-out').textContent = `${formatTime(state.t)}${state.follow ? ' (clock)' : ''}`;
  updateTiles();
  syncUrl();
}

/** Follows the world clock (the drawn time is its now), or holds the drawn time. */
function setFollow(on) {
  state.follow = Boolean(on) && clockNow !== null;
  $('follow').checked = state.follow;
  if (state.follow) {
    state.playing = false;
    $('play').textContent = 'Play';
    setTime(clockNow());
  } else {
    setTime(state.t);
  }
}

function setupControls() {
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    const move = (m) => {
      state.camera.yaw = (state.camera.yaw + m.movementX * 0.2 + 360) % 360;
      state.camera.pitch = clamp(state.camera.pitch - m.movementY * 0.2, -89.9, 89.9);
    };
    canvas.addEventListener('pointermove', move);
    canvas.addEventListener('pointerup', () => canvas.removeEventListener('pointermove', move), { once: true });
  });
  canvas.addEventListener('wheel', (e) => {
    speed = clamp(speed * (e.deltaY < 0 ? 1.25 : 0.8), 5, 20000);
    e.preventDefault();
  }, { passive: false });
  window.addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    keys.add(e.key.toLowerCase());
  });
  window.addEventListener('keyup', (e) => keys.delete(e.key.toLowerCase()));
  window.addEventListener('blur', () => keys.clear());

  const time = $('time');
  // Moving the slider holds the time it names: the clock is no longer followed.
  time.addEventListener('input', () => {
    state.follow = false;
    $('follow').checked = false;
    setTime(Number(time.value));
  });
  $('follow').checked = state.follow;
  $('follow').addEventListener('change', () => setFollow($('follow').checked));
  $('play').addEventListener('click', () => {
    state.playing = !state.playing;
    if (state.playing && state.follow) setFollow(false);
    $('play').textContent = state.playing ? 'Pause' : 'Play';
  });

  const quality = $('quality');
  quality.value = state.quality;
  quality.addEventListener('change', () => {
    state.quality = quality.value;
    client.quality = state.quality;
    updateTiles();
    syncUrl();
  });

  const world = $('world');
  world.addEventListener('change', () => switchWorld(world.value));
  $('seed-go').addEventListener('click', () => {
    const s = $('seed').value.trim();
    if (/^[0-9]+$/.test(s)) switchWorld(s);
    else showError(`a seed is a decimal u64, got "${s}"`);
  });

  const clock = $('sun-clock');
  const az = $('sun-az');
  const el = $('sun-el');
  const sunChanged = () => {
    state.sun = clock.checked ? null : [Number(az.value), Number(el.value)];
    az.disabled = el.disabled = clock.checked;
    $('sun-out').textContent = state.sun ? `${state.sun[0]}°, ${state.sun[1]}°` : 'clock';
    updateTiles();
    syncUrl();
  };
  if (state.sun) {
    clock.checked = false;
    az.value = String(state.sun[0]);
    el.value = String(state.sun[1]);
  }
  clock.addEventListener('change', sunChanged);
  az.addEventListener('change', sunChanged);
  el.addEventListener('change', sunChanged);
  sunChanged();
}

function renderLayerToggles() {
  const box = $('layers');
  box.textContent = '';
  for (const l of worldInfo.layers) {
    const label = document.createElement('label');
    const input = document.createElement('input');
    input.type = 'checkbox';
    input.checked = !state.layers || state.layers.includes(l.name);
    input.addEventListener('change', () => {
      const on = [...box.querySelectorAll('input')].filter((i) => i.checked).map((i) => i.dataset.layer);
      state.layers = on.length === worldInfo.layers.length ? null : on;
      updateTiles();
      syncUrl();
    });
    input.dataset.layer = l.name;
    label.append(input, ` ${l.name}`);
    box.append(label);
  }
}

/** Moves the camera from the keys held; returns true when it moved. */
function fly(dt) {
  const { forward, right } = basis(state.camera);
  const v = speed * (keys.has('shift') ? 5 : 1) * dt;
  const move = [0, 0, 0];
  const add = (d, k) => { for (let i = 0; i < 3; i++) move[i] += d[i] * k; };
  if (keys.has('w')) add(forward, v);
  if (keys.has('s')) add(forward, -v);
  if (keys.has('d')) add(right, v);
  if (keys.has('a')) add(right, -v);
  if (keys.has('r')) move[2] += v;
  if (keys.has('f')) move[2] -= v;
  if (move.every((m) => m === 0)) return false;
  state.camera.x += move[0];
  state.camera.y += move[1];
  state.camera.z = Math.max(2, state.camera.z + move[2]);
  return true;
}

/** True when every wanted tile is drawn. */
function settled() {
  return (
    worldInfo !== null &&
    skyIsCurrent() &&
    wanted.every((k) => tiles.get(k)?.state === 'ready') &&
    wanted.every((k) => !shadowJobs.has(k))
  );
}

// ---------------------------------------------------------------------------
// Main loop and start-up.
// ---------------------------------------------------------------------------

let lastFrame = performance.now();
/**
 * What the last drawn frame showed: the state, the canvas size, the tiles and whether
 * the textures had arrived. A frame that would show the same is not drawn again, so an
 * idle viewer costs no GPU (or, under software GL, no CPU the tile server needs).
 * `continuous` draws every frame regardless (frame-time measurements).
 */
let lastDrawn = '';
/** What the last drawn frame showed but for the time (the clock or play moves it every frame). */
let lastDrawnStill = '';
/**
 * What the last drawn frame cost: the longest wait between two frames since it was
 * drawn (ms; where software GL blocks the page while it draws), and when that wait
 * ended.
 */
let drawCost = 0;
let drawCostEnd = 0;
let continuous = false;
let lastPlan = 0;
let lastPlanCamera = '';
let lastUrlSync = 0;
let lastPlayStep = 0;
/** Canonical frames of world time per second of play. */
const PLAY_FRAMES_PER_SECOND = 4;

function frame(now) {
  const dt = Math.min((now - lastFrame) / 1000, 0.1);
  if (now - lastFrame > drawCost) {
    drawCost = now - lastFrame;
    drawCostEnd = now;
  }
  lastFrame = now;
  const started = performance.now();
  fly(dt);
  const c = state.camera;
  const camKey = [c.x, c.y, c.z, c.yaw, c.pitch, c.fov].map((v) => Math.round(v)).join(',');
  if (worldInfo && camKey !== lastPlanCamera && now - lastPlan > 200) {
    lastPlan = now;
    lastPlanCamera = camKey;
    updateTiles();
    if (now - lastUrlSync > 1000) {
      lastUrlSync = now;
      syncUrl();
    }
  }
  if ((state.playing || state.follow) && worldInfo) {
    // Following the clock, the drawn time is its now; playing, the time runs at
    // PLAY_FRAMES_PER_SECOND canonical frames a second. Tiles animate between their
    // keyframes every frame, and are re-planned (new keyframes, prefetch) a few times a
    // second.
    if (state.follow) {
      state.t = clockNow();
    } else {
      const period = Math.min(...worldInfo.layers.map((l) => l.frame_seconds));
      state.t = clamp(state.t + dt * PLAY_FRAMES_PER_SECOND * period, 0, worldInfo.max_time);
    }
    if (now - lastPlayStep > 250) {
      lastPlayStep = now;
      setTime(state.t);
    }
  }
  strikesPassed();
  deriveShadows(SHADOW_BUDGET_MS);
  const still = [
    flashes.length,
    JSON.stringify({ ...state, t: 0 }),
    canvas.clientWidth,
    canvas.clientHeight,
    window.devicePixelRatio,
    wanted.join(';'),
    wanted.filter((k) => tiles.get(k)?.state === 'ready').length,
    instancesDirty,
    skyLoaded && skyLoaded.url,
  ].join('|');
  const shown = `${still}|${state.t}`;
  // Flashes and the streaks around the eye move every frame. When only the time moved,
  // a frame whose drawing held the page up for longer than TIME_FRAME_MS (software GL)
  // is followed by as long without drawing, so the page keeps answering (fetches,
  // input) while the clock runs.
  const moving = flashes.length > 0 || stats.eyeRate > 0;
  const timeOnly = still === lastDrawnStill;
  const due = !timeOnly || now - drawCostEnd >= drawCost - TIME_FRAME_MS;
  if (skyInfo && (continuous || moving || (shown !== lastDrawn && due))) {
    draw();
    viewerStats.frames++;
    lastDrawn = shown;
    lastDrawnStill = still;
    drawCost = 0;
    drawCostEnd = now;
  }
  const cpu = performance.now() - started;
  stats.frameMs = stats.frameMs ? stats.frameMs * 0.9 + cpu * 0.1 : cpu;
  stats.frameInterval = stats.frameInterval ? stats.frameInterval * 0.9 + dt * 100 : dt * 1000;
  updateHud();
  requestAnimationFrame(frame);
}

function updateHud() {
  const ready = wanted.filter((k) => tiles.get(k)?.state === 'ready').length;
  const kb = (b) => `${(b / 1024).toFixed(1)} KiB`;
  $('hud').textContent = [
    `frame      ${stats.frameMs.toFixed(2)} ms cpu, ${(stats.frameInterval || 0).toFixed(1)} ms interval`,
    `tiles      ${ready}/${wanted.length} loaded, ${inFlight} in flight, ${drawnTiles().length} drawn`,
    `billboards ${stats.billboards}, ${stats.drawCalls} draw calls`,
    `fetched    ${stats.fetched} (${kb(stats.bodyBytes)} bodies, ${kb(stats.transferBytes)} on the wire)`,
    `revalidated ${stats.revalidations} (304), ${stats.reused} immutable reused, ${stats.prefetched} prefetched, ${stats.deltas} deltas`,
    `shadows    ${stats.shadows} derived (${stats.shadowMs.toFixed(0)} ms), ${shadowJobs.size} to do`,
    `camera     ${[c().x, c().y, c().z].map((v) => v.toFixed(0)).join(', ')}  yaw ${c().yaw.toFixed(0)}° pitch ${c().pitch.toFixed(0)}°`,
    `weather    ${stats.eyeRate > 0 ? `${stats.eyeSnow ? 'snow' : 'rain'} ${stats.eyeRate.toFixed(1)} mm/h at the eye` : 'dry at the eye'}, ${stats.precipitationTiles} wet tiles, ${stats.strikes} strikes near, ${stats.flashes} flashes`,
    `sun        ${currentSun().map((v) => Number(v).toFixed(0)).join('°, ')}°${state.sun ? '' : ' (clock)'}`,
  ].join('\n');
  function c() { return state.camera; }
}

async function switchWorld(name) {
  state.world = name;
  $('error').hidden = true;
  for (const key of [...tiles.keys()]) dropTile(key);
  worldInfo = await client.world(name);
  clockNow = worldClock(worldInfo, { rate: state.rate });
  const world = $('world');
  if (![...world.options].some((o) => o.value === name)) {
    world.append(new Option(`seed ${name}`, name));
  }
  world.value = name;
  const time = $('time');
  time.step = String(Math.min(...worldInfo.layers.map((l) => l.frame_seconds)));
  renderLayerToggles();
  setTime(state.follow ? clockNow() : state.t);
}

async function start() {
  setupControls();
  const list = await client.worldList();
  const world = $('world');
  for (const w of list.worlds) world.append(new Option(`${w.name} (seed ${w.seed})`, w.name));
  await switchWorld(state.world);
  requestAnimationFrame(frame);
}

/** For tests and the console: read-only views of the viewer's state. */
window.cloudscape = {
  state,
  stats,
  settled,
  /** True when nothing is being fetched or waits to be (prefetches included). */
  idle: () => inFlight === 0 && queue.length === 0 && prefetchQueue.length === 0,
  project,
  tiles: () =>
    drawnTiles().map((t) => ({
      layer: t.layerName, z: t.z, x: t.x, y: t.y, origin: t.origin, size: t.size, count: t.billboards.count,
      version: t.billboards.header.version, form: t.billboards.header.form, t0: t.t0, t1: t.t1, gen: `t=${t.t0}&${t.gen}`,
    })),
  /** Whether the drawn time follows the world clock; `follow(on)` as the checkbox does. */
  following: () => state.follow,
  follow: (on) => setFollow(on),
  /** The world clock's now (world seconds), or null before discovery. */
  clockNow: () => (clockNow ? clockNow() : null),
  wanted: () => wanted.slice(),
  /** What the view waits for: wanted tiles by state, shadow derivations queued, requests in flight. */
  waiting: () => {
    const byState = {};
    for (const k of wanted) {
      const st = tiles.get(k)?.state || 'unknown';
      byState[st] = (byState[st] || 0) + 1;
    }
    return { wanted: wanted.length, byState, shadowJobs: shadowJobs.size, inFlight, queued: queue.length, prefetchQueued: prefetchQueue.length };
  },
  /** The strikes of the last /lightning answer around the view. */
  strikes: () => strikes.slice(),
  /** Flashes `strike` now (as when the drawn time passes it); `hold` keeps it lit until `unflash()`. */
  flash: (strike, hold = false) => flash(strike, hold),
  unflash: () => {
    flashes = [];
  },
  /** Rain or snow at the eye: { rate (mm/h), snow }. */
  eyePrecipitation: () => eyePrecipitation(),
  /** A tile product's keyframe URL at the drawn time (`tile`: layer (name), z, x, y). */
  tileUrl: (tile, product) => client.tilePath(worldInfo, tile, product, tileTime(state.t)),
  keyframeOf: (layerName, z, t) => keyframeOf(worldInfo.layers.find((l) => l.name === layerName), z, t, worldInfo.max_time),
  /** Draw every frame (true) or only frames that show something new (false, default). */
  setContinuous: (on) => {
    continuous = Boolean(on);
  },
};

start().catch((e) => {
  showError(e.message);
  throw e;
});
