// Copy Swagger UI and ReDoc from their npm packages into service/static/vendor, so /docs and
// /redoc load nothing from a CDN (the service's own static files; see service/routes/web.py).
import { copyFileSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const web = dirname(dirname(fileURLToPath(import.meta.url)));
const out = join(web, "..", "service", "static", "vendor");
const files = {
  "swagger-ui-dist/swagger-ui-bundle.js": "swagger-ui/swagger-ui-bundle.js",
  "swagger-ui-dist/swagger-ui.css": "swagger-ui/swagger-ui.css",
  "swagger-ui-dist/favicon-32x32.png": "swagger-ui/favicon-32x32.png",
  "swagger-ui-dist/LICENSE": "swagger-ui/LICENSE",
  "redoc/bundles/redoc.standalone.js": "redoc/redoc.standalone.js",
  "redoc/LICENSE": "redoc/LICENSE",
};
for (const [src, dst] of Object.entries(files)) {
  mkdirSync(dirname(join(out, dst)), { recursive: true });
  copyFileSync(join(web, "node_modules", src), join(out, dst));
}
// ReDoc's sidebar credit loads its logo from cdn.redoc.ly: point it at an empty local SVG
// (the credit's text stays); a ReDoc that no longer has that URL fails the build here
const redoc = join(out, "redoc/redoc.standalone.js");
const logo = "https://cdn.redoc.ly/redoc/logo-mini.svg";
const text = readFileSync(redoc, "utf8");
if (!text.includes(logo)) throw new Error(`${redoc}: ${logo} not found; check what ReDoc loads`);
writeFileSync(redoc, text.replaceAll(logo, "/vendor/redoc/logo-mini.svg"));
writeFileSync(join(out, "redoc/logo-mini.svg"), '<svg xmlns="http://www.w3.org/2000/svg" width="1" height="1"/>\n');
console.log(`vendored ${Object.keys(files).length} files into ${out}`);
