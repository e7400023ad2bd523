// A static server for the example (node only, no dependencies):
//
//   node serve.mjs [--port 8090] [--cloudscape http://127.0.0.1:8080]
//
// serves this folder at `/`, three.js from node_modules (`npm ci` first) at `/three/`,
// and passes `/v1/…` and `/client/…` (the JS client module) through to the cloudscape
// server, so the page, three.js and the tiles share one origin. A page given
// `?server=ORIGIN` fetches tiles from that origin directly instead (cross-origin: the
// server must send CORS headers).

import { createReadStream, statSync } from 'node:fs';
import { createServer } from 'node:http';
import { extname, join, normalize, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

const here = fileURLToPath(new URL('.', import.meta.url));
const arg = (name, fallback) => {
  const i = process.argv.indexOf(`--${name}`);
  return i > 0 ? process.argv[i + 1] : fallback;
};
const port = Number(arg('port', '8090'));
const upstream = arg('cloudscape', 'http://127.0.0.1:8080').replace(/\/+$/, '');

const TYPES = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.wasm': 'application/wasm',
  '.json': 'application/json',
  '.css': 'text/css',
};

/** The file a path names under `root`, or null when it leaves `root` or is missing. */
function fileUnder(root, rel) {
  const path = resolve(root, normalize(`.${rel}`));
  if (!path.startsWith(resolve(root))) return null;
  try {
    const s = statSync(path);
    if (s.isDirectory()) return fileUnder(root, join(rel, 'index.html'));
    return path;
  } catch {
    return null;
  }
}

async function proxy(req, res) {
  // The body is passed on decoded (fetch undoes gzip, not every encoding the browser
  // accepts), so ask for identity.
  const headers = { 'accept-encoding': 'identity' };
  if (req.headers['if-none-match']) headers['if-none-match'] = req.headers['if-none-match'];
  try {
    const r = await fetch(`${upstream}${req.url}`, { headers });
    const out = {};
    r.headers.forEach((v, k) => {
      // fetch decoded the body: send it as it is now.
      if (!['content-encoding', 'content-length', 'transfer-encoding', 'connection'].includes(k)) out[k] = v;
    });
    res.writeHead(r.status, out);
    res.end(Buffer.from(await r.arrayBuffer()));
  } catch (e) {
    res.writeHead(502, { 'content-type': 'text/plain' });
    res.end(`cloudscape at ${upstream}: ${e.message}`);
  }
}

const server = createServer((req, res) => {
  const path = decodeURIComponent(new URL(req.url, 'http://x').pathname);
  if (path.startsWith('/v1/') || path.startsWith('/client/')) return void proxy(req, res);
  const file = path.startsWith('/three/')
    ? fileUnder(join(here, 'node_modules', 'three'), path.slice('/three'.length))
    : fileUnder(here, path);
  if (!file || file.includes(`${join(here, 'node_modules')}`) && !path.startsWith('/three/')) {
    res.writeHead(404, { 'content-type': 'text/plain' });
    res.end('not found');
    return;
  }
  res.writeHead(200, { 'content-type': TYPES[extname(file)] || 'application/octet-stream', 'cache-control': 'no-cache' });
  createReadStream(file).pipe(res);
});
server.listen(port, '127.0.0.1', () => console.log(`example at http://127.0.0.1:${server.address().port}/ (tiles from ${upstream})`));
