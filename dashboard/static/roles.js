// The Actors table (one row per actor, robot actor, evaluator and demo source) and the collapsed process table.
import { esc, num, pct, seconds, DASH } from "./format.js";

const ACTING_ROLES = { actor: "actor", robot: "robot", eval: "evaluator", demos: "demo source" };

/** Counter groups of the process table: [prefix, heading, what the group means]. First match wins. */
const GROUPS = [
  ["ingest_rejected_", "ingest refused", "episodes the replay refused, by reason (never stored, never acked)"],
  ["ingest_dropped_", "ingest dropped", "episodes dropped unacked (the actor resends them)"],
  ["ingest_", "ingest", "episodes arriving at the replay over Zenoh"],
  ["zmq_rejected_", "sample requests refused", "learner requests the replay refused, by reason"],
  ["zmq_", "sample service", "the replay's ZeroMQ sample service"],
  ["weights_", "weights", "versioned weights: what this role runs, received, refused"],
  ["reach_", "reachability", "reachability tests while acting (top-K candidates)"],
  ["unreachable_", "unreachable ends", "episodes that ended on a pose the arm could not take, by reason"],
  ["loss/", "TD loss", "last update's loss per depth"],
  ["q_chosen/", "chosen-voxel Q", "last update's Q of the chosen voxel per depth"],
  ["eval_", "evaluation", "the latest greedy evaluation"],
  ["demo", "demos", "demonstrations sent to the replay"],
];
const OUTBOX = new Set(["sent", "acked", "duplicates", "rejected", "resent", "dropped", "bad_acks", "unmatched_acks",
  "forged_acks", "outbox_pending"]);
/** One line of help per well-known counter (shown on hover). */
const HELP = {
  episodes: "episodes finished", env_steps: "decisions executed (next-best poses)", successes: "episodes that succeeded",
  success_rate: "share of this process's episodes that succeeded", unreachable_rate: "share that ended unreachable",
  updates: "gradient updates applied", updates_per_s: "gradient updates per second (recent window)",
  samples: "transitions trained on", samples_per_s: "transitions sampled per second",
  weights_version: "weights version this process runs", weights_latency_s: "publish-to-adopt delay of the last weights",
  size_transitions: "transitions stored", samples_per_insert: "transitions sampled per transition inserted",
  outbox_pending: "episodes sent and not yet acknowledged", sent: "episodes sent", acked: "episodes acknowledged",
  resent: "episodes sent again after no ack", rejected_messages: "malformed status messages the dashboard refused",
};

/** Env steps per second per actor, from successive polls of its env_steps counter. */
class Rates {
  constructor() { this.last = {}; this.rate = {}; }
  update(key, value, t) {
    const prev = this.last[key];
    if (prev && t > prev.t && value >= prev.v) {
      const r = (value - prev.v) / (t - prev.t);
      // A poll every second is noisy: smooth over ~10 s, but follow a restart (value went down) at once.
      this.rate[key] = this.rate[key] === undefined ? r : 0.8 * this.rate[key] + 0.2 * r;
    }
    if (!prev || t - prev.t >= 1) this.last[key] = { v: value, t };
    return this.rate[key];
  }
}
const envRates = new Rates();

function stateCell(r) {
  const word = r.state_word || (r.alive ? r.state : "gone");
  return `<td class="state state-${esc(word)}" title="reported: ${esc(r.reported_state ?? "nothing yet")}">${esc(word)}</td>`;
}

export function renderActors(tbody, status) {
  const learnerVersion = status.summary?.weights_version;
  const rows = status.roles.filter(r => r.role in ACTING_ROLES);
  rows.sort((a, b) => Object.keys(ACTING_ROLES).indexOf(a.role) - Object.keys(ACTING_ROLES).indexOf(b.role)
    || a.instance.localeCompare(b.instance, "en", { numeric: true }));
  tbody.innerHTML = rows.map(r => {
    const c = r.counters || {};
    const isEval = r.role === "eval", isDemo = r.role === "demos";
    const lag = isDemo || learnerVersion == null || c.weights_version == null ? null : learnerVersion - c.weights_version;
    const rate = r.alive && c.env_steps != null ? envRates.update(r.instance, c.env_steps, status.time) : null;
    const episodes = isDemo ? c.demo_episodes : isEval ? null : c.episodes;
    const success = isEval ? c.eval_success : c.success_rate;
    const unreachable = isEval ? c.eval_unreachable : c.unreachable_rate ?? (c.episodes ? c.unreachable / c.episodes : null);
    return `<tr data-role="${esc(r.role)}" data-instance="${esc(r.instance)}">` +
      `<td>${esc(r.instance)}</td><td>${ACTING_ROLES[r.role]}</td>${stateCell(r)}` +
      `<td class="n">${lag == null ? DASH : num(lag)}</td><td class="n">${num(episodes)}</td>` +
      `<td class="n">${isDemo ? DASH : pct(success)}${isEval && c.eval_version != null ? ` <small>(v${num(c.eval_version)})</small>` : ""}</td>` +
      `<td class="n">${isDemo ? DASH : pct(unreachable)}</td><td class="n">${rate == null ? DASH : num(rate)}</td>` +
      `<td class="n">${isDemo ? DASH : seconds(c.weights_latency_s)}</td><td class="n">${num(r.restarts ?? 0)}</td></tr>`;
  }).join("") || `<tr><td colspan="10" class="muted">no actors have reported yet</td></tr>`;
}

function groupOf(name) {
  if (OUTBOX.has(name)) return ["outbox", "delivery", "episodes handed to the replay and their acknowledgements"];
  return GROUPS.find(([prefix]) => name.startsWith(prefix)) || ["", "", ""];
}

function counterValue(name, v) {
  if (name.endsWith("_s") && !name.endsWith("_per_s")) return seconds(v);
  if (name.endsWith("_rate") || name.endsWith("_share") || name === "eval_success") return pct(v);
  if (name.endsWith("_bytes")) return `${num(v / 1e6)} MB`;
  return num(v);
}

/** Counters grouped by what they are about; each name carries its explanation as a tooltip. */
function countersHtml(counters) {
  const groups = new Map();
  for (const [name, v] of Object.entries(counters).sort()) {
    const [prefix, heading, help] = groupOf(name);
    const key = heading || "general";
    if (!groups.has(key)) groups.set(key, { help, items: [] });
    const short = prefix && name.startsWith(prefix) && name !== prefix ? name.slice(prefix.length) : name;
    groups.get(key).items.push(`<span title="${esc(HELP[name] || name)}">${esc(short)} <b>${esc(counterValue(name, v))}</b></span>`);
  }
  const order = [...groups.keys()].sort((a, b) => (a === "general" ? -1 : b === "general" ? 1 : a.localeCompare(b)));
  return order.map(k => `<div class="group"><em title="${esc(groups.get(k).help)}">${esc(k)}</em> ${groups.get(k).items.join(" · ")}</div>`).join("");
}

export function renderRoles(tbody, summaryEl, status) {
  summaryEl.textContent = `Processes: ${status.alive} alive, ${status.gone} not running` +
    (status.rejected_messages ? `, ${status.rejected_messages} malformed status messages refused` : "");
  tbody.innerHTML = status.roles.map(r => {
    const age = r.last_seen_age_s == null ? "never" : `${seconds(r.last_seen_age_s)} ago`;
    return `<tr><td>${esc(r.role)}</td><td>${esc(r.instance)}</td>${stateCell(r)}<td>${age}</td>` +
      `<td>${esc(r.pid ?? "")} @ ${esc(r.host ?? "")}</td><td class="n">${num(r.restarts ?? 0)}</td>` +
      `<td class="counters">${countersHtml(r.counters || {})}</td></tr>`;
  }).join("");
}
