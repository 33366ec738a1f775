// Write service/static/build.json: a SHA-256 of every source the build reads (this folder's
// sources and lock file), so a test can tell a committed build that no longer matches them.
// tests/web/test_static_fresh.py computes the same digest in Python: keep the two in step.
import { createHash } from "node:crypto";
import { readdirSync, readFileSync, statSync, writeFileSync } from "node:fs";
import { dirname, join, relative, sep } from "node:path";
import { fileURLToPath } from "node:url";

const web = dirname(dirname(fileURLToPath(import.meta.url)));
const roots = ["../schemas/json/grammar.schema.json", "index.html", "package.json", "package-lock.json", "vite.config.js", "src", "scripts"];

function walk(path, acc) {
  if (statSync(path).isDirectory()) {
    for (const name of readdirSync(path)) walk(join(path, name), acc);
  } else {
    acc.push(relative(web, path).split(sep).join("/"));
  }
  return acc;
}

const files = roots.flatMap((r) => walk(join(web, r), [])).sort();
const h = createHash("sha256");
for (const f of files) {
  h.update(f + "\0");
  h.update(readFileSync(join(web, f)));
  h.update("\0");
}
const stamp = { sources: h.digest("hex"), files: files.length };
writeFileSync(join(web, "..", "service", "static", "build.json"), JSON.stringify(stamp, null, 2) + "\n");
console.log(`build.json: ${stamp.sources} over ${stamp.files} files`);
