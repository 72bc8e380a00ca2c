// The page's one way to the server: JSON in and out, an error's detail as the message. Every
// request names this tab's view (X-Q3T-View): the run it shows, and the one its embedded
// 3-D viewer shows (the same id is in the viewer's address), apart from other browsers'.
"use strict";
const VIEW = (() => {
  // kept for the tab (a reload keeps its view); getRandomValues also on plain http
  let v = sessionStorage.getItem("q3t-view");
  if (!v) {
    v = Array.from(crypto.getRandomValues(new Uint8Array(12)),
                   (b) => b.toString(16).padStart(2, "0")).join("");
    sessionStorage.setItem("q3t-view", v);
  }
  return v;
})();

async function api(method, url, body) {
  const opts = { method, headers: { "X-Q3T-View": VIEW } };
  if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  const r = await fetch(url, opts);
  const data = r.status === 204 ? null : await r.json().catch(() => null);
  if (!r.ok) {
    const d = data && data.detail;
    // a field of the request's JSON is the field the user typed in: "name: ...", not
    // "body.name: ..." (the API's own word for where)
    const text = typeof d === "string" ? d.replace(/(^|; )body\./g, "$1") : JSON.stringify(d);
    const err = new Error(text);
    err.status = r.status;
    throw err;
  }
  return data;
}
