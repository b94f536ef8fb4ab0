// The operator's buttons, one panel per robot actor (role "robot"): a person judges each episode
// (success / fail), says when the scene is reset, and can stop the arm at any time.
// Each press is POST api/operator/<actor>/<action> (dashboard/operator_buttons.py); its answer is shown.
import { authFetch, refusedText } from "./auth.js";
import { esc } from "./format.js";

/** [action, label, class, what it tells the robot actor] in button order; STOP stands apart. */
const BUTTONS = [
  ["success", "Success", "verdict", "the episode succeeded (reward)"],
  ["fail", "Fail", "verdict", "the episode failed (no reward)"],
  ["reset_done", "Reset done", "", "the scene is set up for the next episode"],
  ["resume", "Resume", "", "carry on after a stop"],
  ["stop", "STOP", "stop", "stop the arm now and pause the actor, the episode is dropped (key: Esc, with one robot)"],
];

/** One robot actor's panel; built once, so a press's answer survives the status polls. */
function panelFor(instance) {
  const panel = document.createElement("div");
  panel.className = "operator";
  panel.dataset.instance = instance;
  panel.innerHTML = `<h3>${esc(instance)} <small class="operator-state"></small></h3>` +
    `<div class="buttons">${BUTTONS.map(([action, label, cls, help]) =>
      `<button type="button" class="${cls}" data-action="${action}" title="${esc(help)}">${label}</button>`).join("")}</div>` +
    `<div class="answer muted" aria-live="polite">no command sent yet</div>`;
  for (const button of panel.querySelectorAll("button")) {
    button.addEventListener("click", () => press(panel, instance, button.dataset.action));
  }
  return panel;
}

/** POST one action and show the dashboard's answer (or why it failed) under the buttons. */
async function press(panel, instance, action) {
  const answer = panel.querySelector(".answer");
  answer.className = "answer muted";
  answer.textContent = `${action}: sending…`;
  try {
    // the token's header: a command always needs it (dashboard/access.py)
    const res = await authFetch(`api/operator/${encodeURIComponent(instance)}/${action}`, { method: "POST" });
    const body = await res.json().catch(() => ({}));
    if (res.status === 401) throw new Error(refusedText(body));
    if (!res.ok) throw new Error(body.detail || `HTTP ${res.status}`);
    answer.className = "answer ok";
    answer.textContent = `${action}: ok (command #${body.seq}, ${new Date().toLocaleTimeString()})`;
  } catch (e) {
    answer.className = "answer error";
    answer.textContent = `${action}: error, ${e.message}`;
  }
}

function stateText(r) {
  if (!r.alive) return "not running";
  const arm = r.info?.arm ? `${r.info.arm}, ` : "";
  return r.counters?.paused ? `${arm}stopped: press Resume to carry on` : `${arm}${r.state_word || r.state}`;
}

/** Escape is STOP while exactly one robot actor is shown (with several, a key cannot say which). */
export function stopOnEscape(container) {
  document.addEventListener("keydown", e => {
    const panels = container.querySelectorAll(".operator");
    if (e.key === "Escape" && panels.length === 1) {
      press(panels[0], panels[0].dataset.instance, "stop");
    }
  });
}

/** Show a panel per robot actor in ``status`` (the section stays hidden while there is none). */
export function renderOperator(section, container, status) {
  const robots = status.roles.filter(r => r.role === "robot");
  section.hidden = robots.length === 0;
  const wanted = new Set(robots.map(r => r.instance));
  for (const panel of [...container.children]) {
    if (!wanted.has(panel.dataset.instance)) panel.remove();
  }
  for (const r of robots) {
    let panel = [...container.children].find(p => p.dataset.instance === r.instance);
    if (!panel) container.appendChild(panel = panelFor(r.instance));
    panel.classList.toggle("paused", Boolean(r.counters?.paused));
    panel.querySelector(".operator-state").textContent = stateText(r);
  }
}
