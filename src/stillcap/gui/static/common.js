// What every page of the stillcap GUI shares: the API call with the session token, background jobs
// followed to their end, and the navigation bar.

const TOKEN = document.querySelector('meta[name="stillcap-token"]')?.content ?? "";

/** fetch() of this server's API with the session token header; JSON in and out by default.
 *  Rejects with an Error carrying the server's message (its "error" key) on a non-2xx answer. */
export async function api(path, { method = "GET", json, body, headers = {}, raw = false } = {}) {
  const h = { "X-Stillcap-Token": TOKEN, ...headers };
  if (json !== undefined) {
    h["Content-Type"] = "application/json";
    body = JSON.stringify(json);
  }
  const resp = await fetch(path, { method, headers: h, body, credentials: "same-origin" });
  if (!resp.ok) {
    let msg = `${resp.status} ${resp.statusText}`;
    try {
      const text = await resp.text();
      try { msg = JSON.parse(text).error ?? text; } catch { msg = text || msg; }
    } catch { /* keep the status */ }
    throw new Error(msg);
  }
  if (raw) return resp;
  const type = resp.headers.get("Content-Type") ?? "";
  return type.includes("application/json") ? resp.json() : resp.text();
}

/** Follow a background job (GET /api/jobs/{id}) until it ends; onProgress(job) on every change.
 *  `cancelButton` (optional) is shown while the job runs; a click asks the server to cancel it
 *  (DELETE /api/jobs/{id}: it stops at its next progress report).
 *  Resolves with the job's result, rejects with its error ("cancelled" when cancelled). */
export async function followJob(job, onProgress = () => {}, cancelButton = null) {
  let last = "";
  if (cancelButton) {
    cancelButton.hidden = false;
    cancelButton.disabled = false;
    cancelButton.onclick = async () => {
      cancelButton.disabled = true;
      try { await api(`/api/jobs/${job.id}`, { method: "DELETE" }); } catch (e) { status(e.message, true); }
    };
  }
  try {
    for (;;) {
      const state = JSON.stringify(job);
      if (state !== last) { onProgress(job); last = state; }
      if (job.status === "done") return job.result;
      if (job.status === "failed" || job.status === "cancelled") throw new Error(job.error ?? job.status);
      await new Promise((r) => setTimeout(r, 150));
      job = await api(`/api/jobs/${job.id}`);
    }
  } finally {
    if (cancelButton) { cancelButton.hidden = true; cancelButton.onclick = null; }
  }
}

/** A progress bar element's update for followJob. */
export function progressInto(bar, text) {
  return (job) => {
    bar.max = 1;
    bar.value = job.fraction ?? 0;
    if (text) text.textContent = `${job.label}: ${job.status}${job.step ? " — " + job.step : ""}`;
  };
}

/** Show a message in the page's status line (id "status"), as an error when `error`. */
export function status(message, error = false) {
  const el = document.getElementById("status");
  if (!el) return;
  el.textContent = message;
  el.classList.toggle("error", error);
}

/** Download the answer of an API GET (with the token header) as a file named `name`. */
export async function download(path, name) {
  const resp = await api(path, { raw: true });
  const blob = await resp.blob();
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}
