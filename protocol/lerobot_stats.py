"""Feature statistics as LeRobot v3.0 stores them: per episode in the episodes table, merged in stats.json.

LeRobot normalises inputs with these, so they follow its shapes: a vector feature gets one value
per element (axis 0 reduced), an image one value per channel with shape (C, 1, 1), scaled to
[0, 1]; a feature whose ``info`` says ``"stats": "pooled"`` (a depth map) one value for all of it.
Each has min, max, mean, std, count and the quantiles q01 ... q99; the dataset's figures merge
the episodes' as LeRobot's ``aggregate_stats`` does (weighted means, pooled variance,
count-weighted quantiles).
"""

from __future__ import annotations

import numpy as np

QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}

Stats = dict[str, np.ndarray]




def _image_stats(frames: np.ndarray) -> Stats:
    """uint8 [T, H, W, C]: exact figures from a histogram per channel (a sort of every pixel is slow)."""
    channels = frames.shape[-1]
    flat = frames.reshape(-1, channels)
    out: dict[str, list[float]] = {k: [] for k in ("min", "max", "mean", "std", *QUANTILES)}
    for c in range(channels):
        hist = np.bincount(flat[:, c], minlength=256).astype(np.float64)
        values = np.arange(256, dtype=np.float64) / 255.0
        n = hist.sum()
        mean = (hist * values).sum() / n
        present = np.nonzero(hist)[0]
        cdf = np.cumsum(hist) / n
        out["min"].append(values[present[0]])
        out["max"].append(values[present[-1]])
        out["mean"].append(mean)
        out["std"].append(np.sqrt((hist * (values - mean) ** 2).sum() / n))
        for name, q in QUANTILES.items():
            out[name].append(values[min(int(np.searchsorted(cdf, q)), 255)])
    stats = {k: np.asarray(v, np.float64).reshape(channels, 1, 1) for k, v in out.items()}
    stats["count"] = np.array([len(frames)], np.int64)
    return stats


def feature_stats(ft: dict, values: np.ndarray) -> Stats:
    """One episode's statistics of one feature; ``values`` has the frames on axis 0."""
    if ft["dtype"] == "image":
        return _image_stats(values)
    x = values.astype(np.float64)
    if (ft.get("info") or {}).get("stats") == "pooled":  # e.g. a depth map: one figure for all its pixels
        reduce, shape = {"axis": None}, (1,)
    else:
        reduce, shape = {"axis": 0}, x.shape[1:] or (1,)
    stats = {"min": x.min(**reduce), "max": x.max(**reduce), "mean": x.mean(**reduce), "std": x.std(**reduce)}
    qs = np.quantile(x, list(QUANTILES.values()), **reduce)
    stats.update({name: qs[i] for i, name in enumerate(QUANTILES)})
    stats = {k: np.asarray(v, np.float64).reshape(shape) for k, v in stats.items()}
    stats["count"] = np.array([len(values)], np.int64)
    return stats


def aggregate(episodes: list[Stats]) -> Stats:
    """The dataset's figures of one feature from its episodes' (LeRobot's aggregate_feature_stats)."""
    counts = np.array([int(s["count"][0]) for s in episodes], np.float64)
    total = counts.sum()
    weights = counts.reshape(-1, *([1] * episodes[0]["mean"].ndim)) / total
    means = np.stack([s["mean"] for s in episodes])
    mean = (means * weights).sum(axis=0)
    variance = ((np.stack([s["std"] for s in episodes]) ** 2 + (means - mean) ** 2) * weights).sum(axis=0)
    out = {"min": np.min([s["min"] for s in episodes], axis=0), "max": np.max([s["max"] for s in episodes], axis=0),
           "mean": mean, "std": np.sqrt(variance), "count": np.array([int(total)], np.int64)}
    out.update({q: (np.stack([s[q] for s in episodes]) * weights).sum(axis=0) for q in QUANTILES})
    return out


def to_json(stats: dict[str, Stats]) -> dict:
    """stats.json's layout: feature -> statistic -> nested lists."""
    return {key: {name: value.tolist() for name, value in s.items()} for key, s in stats.items()}
