// The Episodes panel: the latest evaluation, one strip of frames per episode, the chosen pose drawn in.
import { esc, num } from "./format.js";

const AXIS_COLOURS = ["#ef4444", "#22c55e", "#3b82f6"];  // x, y, z of the chosen pose

function outcomeText(ep) {
  const n = ep.decisions;
  switch (ep.outcome) {
    case "success": return `success after ${n} decision${n === 1 ? "" : "s"}`;
    case "timeout": return `timeout: no success in ${n} decisions`;
    case "unreachable":
      return ep.reason === "planning_failed" ? `planning failed at decision ${n}`
        : `unreachable pose at decision ${n}${ep.reason ? ` (${ep.reason.replaceAll("_", " ")})` : ""}`;
    case "failed": return `failed after ${n} decisions`;
    default: return ep.success ? "success" : "ended (reason not recorded)";
  }
}

/** An SVG overlay marking the chosen pose: a ring at its position and its three axes. */
function poseSvg(pose, size) {
  if (!pose || !pose.uv) return "";
  const [h, w] = size, [u, v] = pose.uv;
  const axes = pose.axes.map((tip, k) => tip ? `<line x1="${u}" y1="${v}" x2="${tip[0]}" y2="${tip[1]}" stroke="${AXIS_COLOURS[k]}" stroke-width="${w / 64}"/>` : "").join("");
  const ring = `<circle cx="${u}" cy="${v}" r="${w / 22}" fill="none" stroke="#facc15" stroke-width="${w / 48}"/>`;
  return `<svg class="pose" viewBox="-0.5 -0.5 ${w} ${h}" preserveAspectRatio="none">${axes}${ring}</svg>`;
}

export class EpisodesPanel {
  constructor(root) {
    this.root = root;
    this.camera = null;
    this.data = null;
  }

  update(data) {
    this.data = data;
    if (!data.available) {
      this.root.innerHTML = `<p class="muted">No evaluation episodes yet: they appear after the first evaluation.</p>` +
        (data.errors?.length ? `<p class="muted">${data.errors.map(esc).join("<br>")}</p>` : "");
      return;
    }
    if (!data.cameras.includes(this.camera)) this.camera = data.cameras[0];
    const ok = data.episodes.filter(e => e.outcome === "success").length;
    const picker = data.cameras.length > 1
      ? `<label>camera <select id="episode-camera">${data.cameras.map(c => `<option${c === this.camera ? " selected" : ""}>${esc(c)}</option>`).join("")}</select></label>` : "";
    this.root.innerHTML = `<p class="episodes-head">Weights v${num(data.weights_version)}: ${ok} of ${data.episodes.length} succeeded. ` +
      `The ring marks the next-best pose chosen from each frame (axes x <span style="color:${AXIS_COLOURS[0]}">red</span>, ` +
      `y <span style="color:${AXIS_COLOURS[1]}">green</span>, z <span style="color:${AXIS_COLOURS[2]}">blue</span>); the last frame is where it ended. ${picker}</p>` +
      data.episodes.map(ep => this.episodeHtml(ep)).join("") +
      (data.errors.length ? `<p class="muted">unreadable: ${data.errors.map(esc).join("; ")}</p>` : "");
    this.root.querySelector("#episode-camera")?.addEventListener("change", e => { this.camera = e.target.value; this.update(this.data); });
  }

  episodeHtml(ep) {
    const cam = this.camera;
    const frames = ep.frames.map(f => {
      const pose = f.pose?.[cam];
      const where = !f.action ? "end" : pose?.in_view ? "" : " (pose out of view)";
      const grip = f.action ? (f.action[7] > 0.5 ? "open" : "close") : "";
      return `<figure class="frame"><div class="img"><img src="${esc(f.images[cam])}" alt="seed ${ep.seed} frame ${f.index}" width="${ep.image_size[1]}" height="${ep.image_size[0]}">` +
        `${poseSvg(pose, ep.image_size)}</div><figcaption>${f.action ? `step ${f.index} · ${grip}` : "end"}${where && f.action ? where : ""}</figcaption></figure>`;
    }).join("");
    return `<div class="episode outcome-${esc(ep.outcome)}" data-file="${esc(ep.file)}"><div class="episode-title">` +
      `<b>seed ${esc(ep.seed)}</b> <span class="badge">${esc(outcomeText(ep))}</span></div><div class="strip">${frames}</div></div>`;
  }
}
