// Learning charts (uPlot, vendored): built once, then fed new data from /api/history.
import { num } from "./format.js";

const uPlot = window.uPlot;
const COLOURS = ["#2563eb", "#dc2626", "#16a34a", "#9333ea", "#ea580c", "#0891b2"];

/** The charts of the Learning panel: id -> how to draw it from a /api/history body. */
const CHARTS = [
  { id: "eval-steps", title: "Greedy eval success vs env steps", xLabel: "env steps", yLabel: "success %",
    data: h => evalSuccess(h, "env_steps"), points: true, range: [0, 100] },
  { id: "eval-time", title: "Greedy eval success vs wall-clock", xLabel: "minutes since launch", yLabel: "success %",
    data: h => evalSuccess(h, "minutes"), points: true, range: [0, 100] },
  { id: "td-loss", title: "TD loss per depth", xLabel: "learner step", yLabel: "loss",
    data: h => perDepth(h, "loss/depth") },
  { id: "q-chosen", title: "Q of the chosen voxel per depth", xLabel: "learner step", yLabel: "Q",
    data: h => perDepth(h, "q_chosen/depth") },
  { id: "throughput", title: "Learner rates", xLabel: "learner step", yLabel: "per second",
    data: h => learnerSeries(h, [["updates_per_s", "updates/s"], ["samples_per_s", "samples/s"],
                                 ["replay_samples_per_insert", "samples per insert"]]) },
  { id: "env-rate", title: "Env steps per second (between evaluations)", xLabel: "minutes since launch",
    yLabel: "env steps/s", points: true,
    data: h => xy(h.eval.series, "minutes", [["env_steps_per_s", "env steps/s"]]) },
  { id: "replay-fill", title: "Replay fill", xLabel: "learner step", yLabel: "transitions",
    data: h => replayFill(h) },
];

function evalSuccess(h, xName) {
  const s = h.eval.series, episodes = [];
  const out = xy(s, xName, [["success_rate", "success", v => v * 100]], i => episodes.push(s.episodes?.[i]));
  out.episodes = episodes;
  return out;
}

function perDepth(h, prefix) {
  const names = Object.keys(h.learner.series).filter(k => k.startsWith(prefix)).sort();
  return learnerSeries(h, names.map(n => [n, `depth ${n.slice(prefix.length)}`]));
}

function learnerSeries(h, columns) {
  return xy(h.learner.series, "step", columns.filter(([c]) => c in h.learner.series));
}

function replayFill(h) {
  const out = learnerSeries(h, [["replay_replay_size", "stored"]]);
  if (h.replay_capacity) {
    out.labels.push(`capacity ${num(h.replay_capacity)}`);
    out.data.push(out.data[0].map(() => h.replay_capacity));
  }
  return out;
}

/** Rows with a numeric x, sorted by x (uPlot needs ascending x): {labels, data: [x, ...ys]}. */
function xy(series, xName, columns, onRow = () => {}) {
  const x = series[xName] || [];
  const rows = [];
  for (let i = 0; i < x.length; i++) if (x[i] !== null && x[i] !== undefined) rows.push(i);
  rows.sort((a, b) => x[a] - x[b]);
  rows.forEach(onRow);
  const data = [rows.map(i => x[i])];
  for (const [name, , f] of columns) data.push(rows.map(i => (series[name]?.[i] ?? null) === null ? null : (f ? f(series[name][i]) : series[name][i])));
  return { labels: columns.map(c => c[1]), data };
}

export class LearningCharts {
  constructor(container) {
    this.container = container;
    this.plots = {};   // id -> uPlot
    this.shapes = {};  // id -> series labels the plot was built with
    this.extra = {};   // id -> per-point extras (episode counts)
    for (const c of CHARTS) {
      const card = document.createElement("figure");
      card.className = "chart";
      card.innerHTML = `<figcaption>${c.title}</figcaption><div class="plot" id="chart-${c.id}"></div><div class="empty">no data yet</div>`;
      container.appendChild(card);
    }
    window.addEventListener("resize", () => this.resize());
  }

  width(el) { return Math.max(260, el.clientWidth || 360); }

  update(history) {
    for (const c of CHARTS) {
      const { labels, data, episodes } = c.data(history);
      const el = document.getElementById(`chart-${c.id}`);
      el.parentElement.classList.toggle("has-data", data[0].length > 0);
      this.extra[c.id] = episodes;
      const shape = labels.join("|");
      if (!this.plots[c.id] || this.shapes[c.id] !== shape) {
        this.plots[c.id]?.destroy();
        this.plots[c.id] = new uPlot(this.options(c, labels), data, el);
        this.shapes[c.id] = shape;
      } else {
        this.plots[c.id].setData(data);
      }
    }
  }

  options(c, labels) {
    const id = c.id;
    // Off the plot (no cursor: i is null) the legend shows the latest point, so numbers are always visible.
    const latest = (u, v, si, i) => (i == null && u.data[0].length ? [u.data[si][u.data[0].length - 1], u.data[0].length - 1] : [v, i]);
    const value = (u, v0, si, i0) => {
      const [v, i] = latest(u, v0, si, i0);
      if (v === null || v === undefined) return "\u2013";
      if (c.range) {
        const n = this.extra[id]?.[i];
        return `${Math.round(v)} %${n ? ` of ${n} episodes` : ""}`;
      }
      return num(v);
    };
    return {
      width: this.width(document.getElementById(`chart-${id}`)),
      height: 200,
      legend: { live: true },
      cursor: { drag: { x: true, y: false } },
      scales: { x: { time: false }, y: c.range ? { range: c.range } : {} },
      axes: [
        { label: c.xLabel, size: 40, labelSize: 16, values: (u, ticks) => ticks.map(t => num(t)) },
        { label: c.yLabel, size: 56, labelSize: 16, values: (u, ticks) => ticks.map(t => num(t)) },
      ],
      series: [
        { label: c.xLabel, value: (u, v, si, i) => num(latest(u, v, si, i)[0]) },
        ...labels.map((label, k) => ({
          label, stroke: label.startsWith("capacity") ? "#9ca3af" : COLOURS[k % COLOURS.length], width: 2,
          dash: label.startsWith("capacity") ? [6, 4] : undefined, value, spanGaps: true,
          points: { show: c.points ? true : undefined, size: 6 },
        })),
      ],
    };
  }

  resize() {
    for (const [id, plot] of Object.entries(this.plots)) {
      plot.setSize({ width: this.width(document.getElementById(`chart-${id}`)), height: 200 });
    }
  }
}

