// The service's HTTP API, same origin: every call carries the API key kept in this browser
// (localStorage) as X-API-Key; the server scopes jobs to the key's tenant.
const KEY = "forest.apiKey";

export function apiKey() {
  return localStorage.getItem(KEY) || "";
}

export function setApiKey(key) {
  if (key) localStorage.setItem(KEY, key);
  else localStorage.removeItem(KEY);
}

export class ApiError extends Error {
  constructor(status, detail, errors) {
    super(typeof detail === "string" ? detail : `HTTP ${status}`);
    this.status = status;
    this.detail = detail;
    this.errors = errors;
  }
}

const FINISHED = ["completed", "failed", "canceled"];

/** A file asked for (POST /v1/trees) came back 202 with the job that makes it: poll the job
 *  until it ends, then fetch its file (its one artifact). */
async function fileOfJob(job, as) {
  while (!FINISHED.includes(job.state)) {
    await new Promise((resolve) => setTimeout(resolve, 1000));
    job = await api(`/v1/jobs/${job.id}`);
  }
  if (job.state !== "completed" || !job.artifacts.length) {
    throw new ApiError(422, job.error || `the job was ${job.state}`);
  }
  return api(job.artifacts[0].url, { as });
}

/** fetch(path) with the key; rejects with ApiError on non-2xx: the status and the problem
 * body's (RFC 9457) `detail`, and a 422's `errors` (each field's `loc` and `msg`). A file
 * asked for (`as` other than json) that comes back 202 (a job) is followed to its file. */
export async function api(path, { method = "GET", body, as = "json" } = {}) {
  const headers = {};
  const key = apiKey();
  if (key) headers["X-API-Key"] = key;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const res = await fetch(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  if (!res.ok) {
    let detail = `HTTP ${res.status}`;
    let errors;
    try {
      const problem = await res.json();
      detail = problem.detail ?? detail;
      errors = problem.errors;
    } catch {
      // not JSON: keep the status line
    }
    throw new ApiError(res.status, detail, errors);
  }
  if (res.status === 202 && as !== "json") return fileOfJob(await res.json(), as);
  if (as === "json") return res.json();
  if (as === "blob") return res.blob();
  return res.arrayBuffer();
}

/** A 422 `loc` (["body", "grammar", "rules", "S", 0, "weight"]) -> "grammar.rules.S[0].weight". */
export function locPath(loc) {
  let out = "";
  for (const part of loc.slice(loc[0] === "body" ? 1 : 0)) {
    if (typeof part === "number") out += `[${part}]`;
    else out += out ? `.${part}` : part;
  }
  return out;
}
