// HTTP calls to the operator server (docs/ui.md). Every error carries the server's fail-reason.

/** An HTTP answer that was not 2xx: `status` and the server's `failReason`. */
export class ApiError extends Error {
  constructor(status, failReason) {
    super(failReason);
    this.status = status;
    this.failReason = failReason;
  }
}

async function call(method, path, body) {
  const init = { method, headers: {}, credentials: "same-origin" };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let res;
  try {
    res = await fetch(path, init);
  } catch (err) {
    throw new ApiError(0, `no answer from the server (${err.message})`);
  }
  const text = await res.text();
  let data = null;
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    data = null;
  }
  if (!res.ok) {
    const reason = data && typeof data["fail-reason"] === "string" ? data["fail-reason"] : text || res.statusText;
    throw new ApiError(res.status, `${res.status}: ${reason}`);
  }
  return data;
}

export const getConfig = () => call("GET", "/api/config");
export const getState = () => call("GET", "/api/state");
export const getMission = (id) => call("GET", `/api/missions/${encodeURIComponent(id)}`);
export const plan = (body) => call("POST", "/api/plan", body);
export const start = (body) => call("POST", "/api/missions", body);
export const signal = (id, sig) =>
  call("POST", `/api/missions/${encodeURIComponent(id)}/signal`, { signal: sig });
export const cancel = (id) => call("POST", `/api/missions/${encodeURIComponent(id)}/cancel`);
