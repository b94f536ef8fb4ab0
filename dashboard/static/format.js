// Numbers for people: rounded to what matters, units spelled out, "–" for unknown.

const DASH = "\u2013";

/** A number rounded for reading: 12 345, 123, 12.3, 1.23, 0.0123. */
export function num(v, { digits = 3 } = {}) {
  if (v === null || v === undefined || Number.isNaN(Number(v))) return DASH;
  const x = Number(v);
  if (!Number.isFinite(x)) return x > 0 ? "\u221e" : "-\u221e";
  const a = Math.abs(x);
  if (a >= 100 || Number.isInteger(x)) return Math.round(x).toLocaleString("en-US");
  if (a >= 1) return x.toFixed(Math.max(0, digits - 1 - Math.floor(Math.log10(a))));
  if (a === 0) return "0";
  return x.toPrecision(digits - 1).replace(/0+$/, "").replace(/\.$/, "");
}

/** A fraction as a percentage: 0.853 -> "85 %". */
export function pct(v) {
  if (v === null || v === undefined || !Number.isFinite(Number(v))) return DASH;
  return `${Math.round(Number(v) * 100)} %`;
}

/** A duration in seconds: 0.0103 -> "10 ms", 4.2 -> "4.2 s", 300 -> "5.0 min". */
export function seconds(v) {
  if (v === null || v === undefined || !Number.isFinite(Number(v))) return DASH;
  const x = Number(v);
  if (x < 1) return `${Math.round(x * 1000)} ms`;
  if (x < 120) return `${x.toFixed(1)} s`;
  if (x < 7200) return `${(x / 60).toFixed(1)} min`;
  return `${(x / 3600).toFixed(1)} h`;
}

/** A byte count: 2147483648 -> "2.1 GB". */
export function bytes(v) {
  if (v === null || v === undefined || !Number.isFinite(Number(v))) return DASH;
  const units = ["B", "kB", "MB", "GB", "TB"];
  let x = Number(v), i = 0;
  while (Math.abs(x) >= 1000 && i < units.length - 1) { x /= 1000; i += 1; }
  return `${i ? x.toFixed(1) : Math.round(x)} ${units[i]}`;
}

/** HTML-escaped text. */
export function esc(s) {
  return String(s ?? "").replace(/[&<>"']/g, c => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
}

export { DASH };
