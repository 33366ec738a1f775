// Drives Debian's Chromium (playwright-core from web/node_modules) through the farm's page
// served by `forest serve` on loopback; prints one JSON object of what it saw (the pytest
// side, test_page.py, asserts on it) and writes a screenshot.
// usage: node page.mjs BASE_URL KEY OTHER_TENANT_JOB OUT_DIR
import { chromium } from "../../web/node_modules/playwright-core/index.mjs";

const [base, key, otherJob, out] = process.argv.slice(2);
const seen = { requests: [], offsite: [], console: [], steps: {} };
const step = (name, value) => {
  seen.steps[name] = value;
};

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  // no GPU here: WebGL on SwiftShader
  args: ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-sandbox"],
});
try {
  const context = await browser.newContext({ viewport: { width: 1400, height: 1100 } });
  context.on("request", (r) => {
    const url = r.url();
    seen.requests.push(url);
    if (!/^(blob|data):/.test(url) && !url.startsWith("http://127.0.0.1:")) seen.offsite.push(url);
  });
  // anything not on loopback is refused (and recorded above): the page must work offline
  await context.route((url) => !["127.0.0.1"].includes(url.hostname) && url.protocol.startsWith("http"), (r) => r.abort());
  const page = await context.newPage();
  page.on("console", (m) => {
    if (m.type() === "error") seen.console.push(m.text());
  });
  page.on("pageerror", (e) => seen.console.push(String(e)));

  // -- without a key the keyed server refuses, and the page says how to make one; the presets
  // are public, so they are listed all the same
  await page.goto(base + "/");
  await page.waitForFunction(() => document.querySelector("#key-status").textContent !== "", null, { timeout: 10000 });
  step("no_key_status", await page.textContent("#key-status"));
  await page.waitForFunction(() => document.querySelectorAll(".preset").length >= 8, null, { timeout: 15000 });
  step("no_key_presets", await page.$$eval(".preset", (cards) => cards.map((c) => c.dataset.name)));
  step("no_key_help", (await page.isVisible("#key-help")) ? await page.innerText("#key-help") : null);
  step("no_key_jobs_table", await page.isVisible("#jobs"));
  await page.screenshot({ path: `${out}/page-no-key.png` });

  // -- a wrong key: the page says the server refused it
  await page.fill("#api-key", "fk_000000000000_wrong");
  await page.dispatchEvent("#api-key", "change");
  await page.waitForFunction(() => document.querySelector("#key-help-title").textContent.includes("refused"), null, { timeout: 10000 });
  step("wrong_key_status", await page.textContent("#key-status"));
  step("wrong_key_help", (await page.isVisible("#key-help")) ? await page.innerText("#key-help") : null);

  // -- the key, kept in this browser, is sent as X-API-Key; the explanation goes
  await page.fill("#api-key", key);
  await page.dispatchEvent("#api-key", "change");
  await page.waitForSelector("#key-help", { state: "hidden", timeout: 10000 });
  step("key_help_with_key", await page.isVisible("#key-help"));
  step("jobs_table_with_key", await page.isVisible("#jobs"));
  step("key_status_with_key", await page.textContent("#key-status"));
  await page.reload();
  step("key_kept", (await page.inputValue("#api-key")) === key);
  await page.waitForFunction(() => document.querySelectorAll(".preset").length >= 8, null, { timeout: 15000 });
  await page.waitForFunction(() => [...document.querySelectorAll(".preset img")].every((i) => i.complete && i.naturalWidth > 0), null, { timeout: 15000 });
  step("presets", await page.$$eval(".preset", (cards) => cards.map((c) => c.dataset.name)));
  step("gallery_images", await page.$$eval(".preset img", (imgs) => imgs.filter((i) => i.naturalWidth > 0).length));

  // -- the schema check as you type: a negative max_depth is flagged before any request
  await page.click('.preset[data-name="birch"]');
  const birch = JSON.parse(await page.inputValue("#grammar"));
  await page.fill("#grammar", JSON.stringify({ ...birch, max_depth: -3 }, null, 2));
  step("schema_error", await page.textContent("#err-grammar"));

  // -- a grammar the schema allows but the server refuses: its 422 message on the grammar field
  const bad = { axiom: "S", rules: { S: [{ piece: "I", successors: [{ symbol: "Z" }] }] } };
  await page.fill("#grammar", JSON.stringify(bad, null, 2));
  step("schema_ok_text", await page.textContent("#err-grammar"));
  await page.click("#submit-forest");
  await page.waitForSelector('#err-grammar[data-source="server"]', { timeout: 10000 });
  step("server_grammar_error", await page.textContent("#err-grammar"));
  step("grammar_marked", await page.$eval("#grammar", (t) => t.classList.contains("invalid")));
  // and a bad count on its own field
  await page.click('.preset[data-name="birch"]');
  await page.fill("#trees", "0");
  await page.click("#submit-forest");
  await page.waitForSelector('#err-trees[data-source="server"]', { timeout: 10000 });
  step("server_trees_error", await page.textContent("#err-trees"));
  step("grammar_error_after_trees", await page.textContent("#err-grammar"));

  // -- a forest job from the form; the page renders its preview when it completes
  await page.fill("#trees", "2");
  await page.fill("#area-x", "6");
  await page.fill("#area-y", "6");
  await page.selectOption("#format", "usdc");
  await page.check("#auto-render");
  const t0 = Date.now();
  await page.click("#submit-forest");
  await page.waitForSelector('tr[data-kind="forest"][data-state="completed"]', { timeout: 90000 });
  step("forest_s", (Date.now() - t0) / 1000);
  step("forest_row", await page.textContent('tr[data-kind="forest"][data-state="completed"]'));
  await page.waitForSelector('tr[data-kind="render"][data-state="completed"] img.preview', { timeout: 90000 });
  await page.waitForFunction(() => {
    const img = document.querySelector('tr[data-kind="render"][data-state="completed"] img.preview');
    return img && img.complete && img.naturalWidth > 0;
  }, null, { timeout: 15000 });
  step("render_s", (Date.now() - t0) / 1000);
  step("preview_size", await page.$eval('tr[data-kind="render"] img.preview', (i) => [i.naturalWidth, i.naturalHeight]));
  step("render_links", await page.$$eval('tr[data-kind="render"] a.artifact', (as) => as.map((a) => a.textContent)));
  step("job_ids", await page.$$eval("tr.job", (rows) => rows.map((r) => r.dataset.jobId)));
  step("other_tenant_job_shown", (await page.$(`tr[data-job-id="${otherJob}"]`)) !== null);
  // the forest job's log, under its row; a tenant's key shows no workers
  await page.click('tr[data-kind="forest"][data-state="completed"] button.show-log');
  await page.waitForFunction(() => /completed: \d+ artifact/.test(document.querySelector("tr.log")?.textContent ?? ""), null, { timeout: 15000 });
  step("forest_log", await page.textContent("tr.log"));
  step("workers_status", await page.textContent("#workers-status"));
  step("workers_table_shown", await page.isVisible("#workers"));
  // an artifact downloads (fetched with the key, saved by the browser)
  const [download] = await Promise.all([
    page.waitForEvent("download", { timeout: 15000 }),
    page.click('tr[data-kind="forest"] a.artifact'),
  ]);
  step("download_name", download.suggestedFilename());

  // -- the 3D viewer: one tree as glb with its wind playing
  await page.click('.preset[data-name="birch"]');
  await page.fill("#frames", "24");
  await page.click("#view-tree");
  await page.waitForSelector('#viewer[data-state="ready"]', { timeout: 60000 });
  await page.waitForTimeout(500);
  const pixels = () =>
    page.$eval("#viewer-canvas", (c) => {
      const copy = document.createElement("canvas");
      copy.width = c.width;
      copy.height = c.height;
      const g = copy.getContext("2d");
      g.drawImage(c, 0, 0);
      const d = g.getImageData(0, 0, c.width, c.height).data;
      const bg = [0xdf, 0xe8, 0xee]; // the viewer's clear colour (viewer.js BACKGROUND)
      let drawn = 0;
      const sig = [];
      for (let i = 0; i < d.length; i += 4) {
        const off = Math.abs(d[i] - bg[0]) + Math.abs(d[i + 1] - bg[1]) + Math.abs(d[i + 2] - bg[2]);
        if (off > 24) drawn += 1;
        sig.push(d[i] + d[i + 1] + d[i + 2]);
      }
      return { drawn, total: d.length / 4, sig };
    });
  const a = await pixels();
  await page.waitForTimeout(700);
  const b = await pixels();
  let changed = 0;
  for (let i = 0; i < a.sig.length; i += 1) if (Math.abs(a.sig[i] - b.sig[i]) > 12) changed += 1;
  step("canvas", { drawn: a.drawn, total: a.total, changed_between_frames: changed });
  step("clips", await page.getAttribute("#viewer", "data-clips"));
  step("viewer_msg", await page.textContent("#viewer-msg"));
  // levels of detail: the tree's LOD0 up close, a lighter level from far away
  step("levels", await page.getAttribute("#viewer", "data-levels"));
  step("lod_near", await page.getAttribute("#viewer", "data-lod"));
  await page.evaluate(() => window.forestViewer.zoom(12));
  // the level changes on the next drawn frame: wait for it (a busy machine draws slowly)
  await page.waitForFunction(() => document.querySelector("#viewer").dataset.lod !== "0", null, { timeout: 15000 }).catch(() => {});
  step("lod_far", await page.getAttribute("#viewer", "data-lod"));
  await page.evaluate(() => window.forestViewer.zoom(1 / 12));
  // the tree shown downloads as GLB and as USD
  const names = [];
  for (const button of ["#download-glb", "#download-usd"]) {
    const [saved] = await Promise.all([page.waitForEvent("download", { timeout: 120000 }), page.click(button)]);
    names.push(saved.suggestedFilename());
  }
  step("tree_downloads", names);

  // -- a small forest as a glb job, shown in the viewer from its scene.glb
  await page.fill("#trees", "2");
  await page.fill("#frames", "12");
  await page.selectOption("#format", "glb");
  const forests = await page.$$eval('tr[data-kind="forest"]', (r) => r.length);
  await page.click("#submit-forest");
  await page.waitForFunction((n) => document.querySelectorAll('tr[data-kind="forest"]').length > n, forests, { timeout: 15000 });
  await page.waitForSelector('tr[data-kind="forest"][data-state="completed"] button.view3d', { timeout: 90000 });
  await page.click('tr[data-kind="forest"][data-state="completed"] button.view3d');
  await page.waitForFunction(() => document.querySelector("#viewer-title").textContent.startsWith("job "), null, { timeout: 60000 });
  await page.waitForTimeout(500);
  const f = await pixels();
  step("forest_canvas", { drawn: f.drawn, total: f.total });
  step("forest_viewer_msg", await page.textContent("#viewer-msg"));

  // -- a recipe (a mixed forest) picked instead of a preset: its 422 on the field it names, then
  // a forest job whose root layer and layer files are listed for download
  await page.waitForFunction(() => document.querySelectorAll(".recipe").length >= 1, null, { timeout: 15000 });
  step("recipes", await page.$$eval(".recipe", (cards) => cards.map((c) => c.dataset.name)));
  await page.click('.recipe[data-name="orchard"]');
  step("recipe_source", await page.$eval("input[name=source][value=recipe]", (r) => r.checked));
  await page.fill("#trees", "2");
  await page.fill("#area-x", "16");
  await page.fill("#area-y", "16");
  await page.fill("#frames", "0");
  await page.click("#submit-forest"); // format is still glb: refused on its field
  await page.waitForSelector('#err-format[data-source="server"]', { timeout: 10000 });
  step("recipe_format_error", await page.textContent("#err-format"));
  await page.selectOption("#format", "usdc");
  const before = await page.$$eval('tr[data-kind="forest"]', (r) => r.length);
  await page.click("#submit-forest");
  await page.waitForFunction((n) => document.querySelectorAll('tr[data-kind="forest"]').length > n, before, { timeout: 15000 });
  await page.waitForFunction(
    () => [...document.querySelectorAll('tr[data-kind="forest"][data-state="completed"]')].some((r) => r.textContent.includes("scene_almond.usdc")),
    null,
    { timeout: 120000 },
  );
  step("recipe_row", await page.$$eval('tr[data-kind="forest"][data-state="completed"]', (rows) =>
    rows.map((r) => r.textContent).find((t) => t.includes("scene_almond.usdc"))));
  await page.screenshot({ path: `${out}/page.png`, fullPage: true });

  // -- the API docs from the service's own files
  await page.goto(base + "/docs");
  await page.waitForSelector(".swagger-ui .info .title", { timeout: 20000 });
  step("swagger_title", await page.textContent(".swagger-ui .info .title"));
  step("swagger_ops", await page.$$eval(".opblock", (o) => o.length));
  await page.goto(base + "/redoc");
  await page.waitForSelector("h1", { timeout: 20000 });
  step("redoc_title", await page.textContent("h1"));
  step("redoc_ops", await page.$$eval("[data-section-id^='operation']", (o) => o.length));
} catch (err) {
  seen.error = String(err && err.stack ? err.stack : err);
} finally {
  await browser.close();
  seen.requests = [...new Set(seen.requests.map((u) => u.replace(/^(https?:\/\/[^/]+\/[^?]*).*$/, "$1")))];
  console.log(JSON.stringify(seen));
}
