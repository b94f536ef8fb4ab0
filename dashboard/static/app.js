// The dashboard page: polls the JSON endpoints and hands each answer to its panel.
// status: every refresh period; history: every few seconds; episodes and Q-attention: every 10 s.
// Unchanged answers (same ETag: the server answered the browser's revalidation with a 304) are not redrawn.
import { authFetch, refusedText } from "./auth.js";
import { LearningCharts } from "./charts.js";
import { EpisodesPanel } from "./episodes.js";
import { renderOperator, stopOnEscape } from "./operator.js";
import { AttentionView } from "./qattention3d.js";
import { renderActors, renderRoles } from "./roles.js";
import { num, pct, seconds } from "./format.js";

const body = document.body;
const REFRESH_MS = Number(body.dataset.refreshMs) || 1000;
window.c2farm = { charts: {}, polls: {}, errors: [] };

const $ = id => document.getElementById(id);
const charts = new LearningCharts($("charts"));
const episodes = new EpisodesPanel($("episodes"));
const attention = new AttentionView($("qattention"));
window.c2farm.charts = charts.plots;
stopOnEscape($("operators"));
let history = null;

function summaryLine(s) {
  const t = s.summary || {};
  const cap = history?.replay_capacity;
  const parts = [
    `updates ${num(t.updates)}${t.updates_per_s != null ? ` (${num(t.updates_per_s)}/s)` : ""}`,
    `env steps ${num(t.env_steps)}`,
    `replay ${num(t.replay_size)}${cap ? ` of ${num(cap)}` : ""} transitions`,
    `weights v${num(t.weights_version)}`,
    `eval success ${pct(t.eval_success)}${t.eval_version != null ? ` (v${num(t.eval_version)})` : ""}`,
  ];
  if (history?.started_at && s.time > history.started_at) parts.unshift(`running for ${seconds(s.time - history.started_at)}`);
  return parts.join(" \u00b7 ");
}

/** Poll ``url`` every ``ms``; ``render`` only when the answer changed. */
function poll(name, url, ms, render) {
  let etag = null;
  const once = async () => {
    try {
      const res = await authFetch(url, { cache: "no-cache" });
      if (res.status === 401) throw new Error(refusedText(await res.json().catch(() => ({}))));
      if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
      const tag = res.headers.get("ETag");
      if (!tag || tag !== etag) {
        render(await res.json());
        etag = tag;
      }
      window.c2farm.polls[name] = (window.c2farm.polls[name] || 0) + 1;
      $("offline").hidden = true;
    } catch (e) {
      $("offline").hidden = false;
      $("offline").textContent = `dashboard unreachable or answering badly (${e.message}); retrying`;
    } finally {
      setTimeout(once, ms);
    }
  };
  once();
}

poll("status", "api/status", REFRESH_MS, s => {
  $("summary").textContent = summaryLine(s);
  $("updated").textContent = `updated ${new Date().toLocaleTimeString()}`;
  renderOperator($("operator-panel"), $("operators"), s);
  renderActors($("actor-rows"), s);
  renderRoles($("role-rows"), $("roles-summary"), s);
});
poll("history", "api/history", Math.max(3000, REFRESH_MS), h => {
  history = h;
  const e = h.eval.rows, l = h.learner.rows;
  $("learning-note").textContent = `${num(e)} evaluations, ${num(l)} learner rows` +
    (l > (h.learner.series.step || []).length ? ` (thinned to ${(h.learner.series.step || []).length} points)` : "");
  charts.update(h);
});
poll("episodes", "api/episodes", 10000, d => episodes.update(d));
poll("qattention", "api/qattention", 10000, q => attention.update(q));
