// The dashboard's token (dashboard/access.py): read from this page's own URL (?token=...), kept in
// sessionStorage for the tab (a reload or a link without it still works), and sent as
// "Authorization: Bearer <token>" on every fetch. What the browser loads by itself (scripts,
// images) is let in by the cookie the server set when it served the page with the token.
const KEY = "c2farm.dashboard.token";

function readToken() {
  const fromUrl = new URLSearchParams(location.search).get("token");
  try {
    if (fromUrl) sessionStorage.setItem(KEY, fromUrl);
    return fromUrl || sessionStorage.getItem(KEY);
  } catch {
    return fromUrl;  // storage refused (private mode, policy): the URL's token for this page
  }
}

const TOKEN = readToken();

/** ``fetch`` with the token's header (when the page has one). */
export function authFetch(url, options = {}) {
  const headers = new Headers(options.headers || {});
  if (TOKEN) headers.set("Authorization", `Bearer ${TOKEN}`);
  return fetch(url, { ...options, headers });
}

/** Why a refused (HTTP 401) answer was refused, in words for the page. */
export function refusedText(body) {
  return `${body?.error || "refused"}: open the dashboard's URL with its token (/?token=..., ` +
    "the token is in the run directory's dashboard.token)";
}
