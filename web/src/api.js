// The service's HTTP API, same origin: every call carries the API key kept in this browser
// (localStorage) as X-API-Key; the server scopes jobs to the key's tenant.
import { EventSourceParserStream } from "eventsource-parser/stream";

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

/** A job's Server-Sent Events (GET /v1/jobs/{id}/events) as { event, data, id }: `state`,
 * `progress`, `log`, then `end`. The browser's EventSource cannot send the key header, so
 * the stream is a fetch parsed by eventsource-parser. It returns when the server closes the
 * stream: after `end`, or at the server's cap on a stream's length (then reconnect with the
 * last `log` event's id as `lastEventId`). */
export async function* jobEvents(jobId, { lastEventId, signal } = {}) {
  const headers = { Accept: "text/event-stream" };
  const key = apiKey();
  if (key) headers["X-API-Key"] = key;
  if (lastEventId) headers["Last-Event-ID"] = lastEventId;
  const res = await fetch(`/v1/jobs/${jobId}/events`, { headers, signal });
  if (!res.ok) {
    let detail = `HTTP ${res.status}`;
    try {
      detail = (await res.json()).detail ?? detail;
    } catch {
      // not JSON: keep the status line
    }
    throw new ApiError(res.status, detail);
  }
  const reader = res.body.pipeThrough(new TextDecoderStream()).pipeThrough(new EventSourceParserStream()).getReader();
  try {
    for (;;) {
      const { value, done } = await reader.read();
      if (done) return;
      yield { event: value.event, data: JSON.parse(value.data), id: value.id };
    }
  } finally {
    reader.cancel().catch(() => {});
  }
}

/** Follow a job's events until it ends (reconnecting past a stream's cap); the job as it
 *  ended. */
export async function untilEnded(job) {
  let lastEventId;
  while (!FINISHED.includes(job.state)) {
    let ended = false;
    for await (const e of jobEvents(job.id, { lastEventId })) {
      if (e.event === "log") lastEventId = e.id;
      if (e.event === "end") ended = true;
    }
    job = await api(`/v1/jobs/${job.id}`);
    if (!ended && !FINISHED.includes(job.state)) await new Promise((resolve) => setTimeout(resolve, 500));
  }
  return job;
}

/** A file asked for (POST /v1/trees) came back 202 with the job that makes it: follow the
 *  job's events until it ends, then fetch its file (its one artifact). */
async function fileOfJob(job, as) {
  job = await untilEnded(job);
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
