// A small static HTTP server on 127.0.0.1 for the check: the Studio app (this folder's web/
// and @foxglove/studio-base's built assets from node_modules), React 17's UMD builds, the layout,
// and recordings, with HTTP Range support (Studio's remote-file source reads MCAP by ranges).
import fs from "node:fs";
import http from "node:http";
import path from "node:path";
import { createRequire } from "node:module";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(import.meta.url);

const TYPES = {
  ".html": "text/html; charset=utf-8",
  ".js": "text/javascript; charset=utf-8",
  ".json": "application/json",
  ".wasm": "application/wasm",
  ".png": "image/png",
  ".ttf": "font/ttf",
  ".woff2": "font/woff2",
  ".mcap": "application/octet-stream",
};

export function studioAssetsDir() {
  return path.join(path.dirname(require.resolve("@foxglove/studio-base/package.json")), "assets");
}

/** Start the server. `files` maps URL paths (such as "/rec/default.mcap") to files on disk. */
export async function startServer({ layoutFile, files = {}, port = 0 }) {
  const assets = studioAssetsDir();
  const routes = new Map(Object.entries({
    "/": path.join(here, "web", "index.html"),
    "/index.html": path.join(here, "web", "index.html"),
    "/boot.js": path.join(here, "web", "boot.js"),
    "/layout.json": layoutFile,
    "/vendor/react.js": require.resolve("react/umd/react.production.min.js"),
    "/vendor/react-dom.js": require.resolve("react-dom/umd/react-dom.production.min.js"),
    ...files,
  }));
  const served = { requests: 0, rangeRequests: 0, notFound: [] };

  const server = http.createServer((req, res) => {
    served.requests += 1;
    const url = new URL(req.url, "http://127.0.0.1");
    if (url.pathname === "/favicon.ico") {
      res.writeHead(204).end();
      return;
    }
    let file = routes.get(url.pathname);
    if (!file && url.pathname.startsWith("/assets/")) {
      const rel = path.normalize(decodeURIComponent(url.pathname.slice("/assets/".length)));
      if (!rel.startsWith("..") && !path.isAbsolute(rel)) { file = path.join(assets, rel); }
    }
    let stat;
    try { stat = file && fs.statSync(file); } catch { stat = undefined; }
    if (!stat || !stat.isFile()) {
      served.notFound.push(url.pathname);
      res.writeHead(404, { "content-type": "text/plain" }).end("not found");
      return;
    }
    const headers = {
      "content-type": TYPES[path.extname(file)] ?? "application/octet-stream",
      "accept-ranges": "bytes",
      "cache-control": "no-store",
      "access-control-allow-origin": "*",
    };
    if (req.method === "HEAD") {
      res.writeHead(200, { ...headers, "content-length": stat.size }).end();
      return;
    }
    const range = /^bytes=(\d*)-(\d*)$/.exec(req.headers.range ?? "");
    if (range) {
      served.rangeRequests += 1;
      let start = range[1] === "" ? stat.size - Number(range[2]) : Number(range[1]);
      let end = range[1] === "" || range[2] === "" ? stat.size - 1 : Number(range[2]);
      end = Math.min(end, stat.size - 1);
      if (start < 0) { start = 0; }
      if (start > end || start >= stat.size) {
        res.writeHead(416, { ...headers, "content-range": `bytes */${stat.size}` }).end();
        return;
      }
      res.writeHead(206, { ...headers, "content-range": `bytes ${start}-${end}/${stat.size}`, "content-length": end - start + 1 });
      fs.createReadStream(file, { start, end }).pipe(res);
      return;
    }
    res.writeHead(200, { ...headers, "content-length": stat.size });
    fs.createReadStream(file).pipe(res);
  });
  await new Promise((resolve, reject) => {
    server.once("error", reject);
    server.listen(port, "127.0.0.1", resolve);
  });
  const base = `http://127.0.0.1:${server.address().port}`;
  return { server, base, served, close: () => new Promise((r) => server.close(r)) };
}
