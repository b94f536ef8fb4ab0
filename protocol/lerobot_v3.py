"""The LeRobot dataset format v3.0, written and read with pyarrow alone (lerobot needs Python 3.12 and torch).

Layout (as lerobot 0.6 writes it): ``meta/info.json``, ``meta/stats.json``, ``meta/tasks.parquet``,
``meta/episodes/chunk-000/file-000.parquet`` (one row per episode: where its frames are, its
task, length and statistics) and ``data/chunk-XXX/file-XXX.parquet`` (one row per frame, many
episodes per file; a new file past 100 MB, a new chunk past 1000 files). Images are embedded in
the data files as PNG (the ``datasets.Image`` struct of bytes and path), so no video codec is
needed. Every frame also carries the automatic features timestamp, frame_index, episode_index,
index and task_index. Arrays keep the Arrow types ``datasets`` gives them: a scalar per frame
for shape (1,), a fixed-size list for a vector, nested lists for 2-D and 3-D arrays.

Nothing here knows c2farm's episodes (``lerobot_demo.py`` maps those to columns).
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from PIL import Image

from protocol import lerobot_stats

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000  #: files per chunk folder
DATA_FILE_SIZE_MB = 100  #: a data file is closed once its frames pass this (uncompressed)
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
DEFAULT_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
IMAGE_TYPE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])


class LeRobotFormatError(ValueError):
    """A dataset that is not (or not readable as) LeRobot v3.0; one line naming what is wrong."""


@dataclass
class Episode:
    """One episode as columns: every feature's values with the frames on axis 0 (images uint8 [T,H,W,3])."""

    task: str
    columns: dict[str, np.ndarray]
    meta: dict[str, object] = field(default_factory=dict)  #: extra episodes-table columns (scalars, lists)

    @property
    def length(self) -> int:
        return len(next(iter(self.columns.values())))


def _arrow_type(ft: dict) -> pa.DataType:
    if ft["dtype"] == "image":
        return IMAGE_TYPE
    value = pa.from_numpy_dtype(np.dtype(ft["dtype"]))
    shape = list(ft["shape"])
    if shape == [1]:
        return value
    if len(shape) == 1:
        return pa.list_(value, shape[0])
    for _ in shape:
        value = pa.list_(value)
    return value


def _hf_feature(ft: dict) -> dict:
    """The ``datasets`` feature (schema metadata) that reads the column back as lerobot declares it."""
    if ft["dtype"] == "image":
        return {"_type": "Image"}
    shape = list(ft["shape"])
    if shape == [1]:
        return {"dtype": ft["dtype"], "_type": "Value"}
    if len(shape) == 1:
        return {"feature": {"dtype": ft["dtype"], "_type": "Value"}, "length": shape[0], "_type": "Sequence"}
    return {"shape": shape, "dtype": ft["dtype"], "_type": f"Array{len(shape)}D"}


def _png(frame: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def _to_arrow(ft: dict, values: np.ndarray) -> pa.Array:
    if ft["dtype"] == "image":
        return pa.array([{"bytes": _png(f), "path": None} for f in values], IMAGE_TYPE)
    shape = list(ft["shape"])
    flat = pa.array(np.ascontiguousarray(values, np.dtype(ft["dtype"])).reshape(-1))
    if shape == [1]:
        return flat
    if len(shape) == 1:
        return pa.FixedSizeListArray.from_arrays(flat, shape[0])
    arr, rows = flat, len(values)
    for size in reversed(shape):
        n = len(arr) // size
        arr = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32) * size), arr)
    assert len(arr) == rows
    return arr


def _from_arrow(ft: dict, column: pa.ChunkedArray, key: str) -> np.ndarray:
    if ft["dtype"] == "image":
        frames = []
        for cell in column.to_pylist():
            if not cell or not cell.get("bytes"):
                raise LeRobotFormatError(f"{key}: an image without embedded bytes (images as files or videos "
                                         "are not read here; this reader takes embedded images)")
            frames.append(np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB")))
        return np.stack(frames) if frames else np.zeros((0, *ft["shape"]), np.uint8)
    arr = column.combine_chunks()
    for _ in range(len(ft["shape"]) if list(ft["shape"]) != [1] else 0):
        arr = arr.flatten()
    values = arr.to_numpy(zero_copy_only=False)
    shape = [int(s) for s in ft["shape"]]
    if values.size != len(column) * int(np.prod(shape)):
        raise LeRobotFormatError(f"{key}: values do not have the declared shape {shape}")
    return values.astype(np.dtype(ft["dtype"])).reshape(len(column), *shape)


class DatasetWriter:
    """Writes episodes one at a time; :meth:`finish` writes the metadata. ``root`` must be empty."""

    def __init__(self, root: Path, fps: int, features: dict[str, dict], robot_type: str, repo_id: str,
                 episode_meta_types: dict[str, pa.DataType] | None = None,
                 data_file_size_mb: float = DATA_FILE_SIZE_MB) -> None:
        self.root, self.fps, self.robot_type, self.repo_id = Path(root), int(fps), robot_type, repo_id
        self.features = {**features, **DEFAULT_FEATURES}
        self.meta_types = episode_meta_types or {}
        self.limit = data_file_size_mb * 1024 * 1024
        self.schema = pa.schema([(k, _arrow_type(ft)) for k, ft in self.features.items()], metadata={
            "huggingface": json.dumps({"info": {"features": {k: _hf_feature(ft) for k, ft in self.features.items()}}})})
        self.tasks: dict[str, int] = {}
        self.rows: list[dict] = []
        self.stats: list[dict[str, lerobot_stats.Stats]] = []
        self.frames = 0
        self.chunk = self.file = 0
        self.file_bytes = 0
        self.writer: pq.ParquetWriter | None = None

    def _data_file(self, nbytes: int) -> pq.ParquetWriter:
        if self.writer is not None and self.file_bytes + nbytes > self.limit and self.file_bytes > 0:
            self.writer.close()
            self.writer, self.file_bytes = None, 0
            self.chunk, self.file = (self.chunk + 1, 0) if self.file == CHUNKS_SIZE - 1 else (self.chunk, self.file + 1)
        if self.writer is None:
            path = self.root / DATA_PATH.format(chunk_index=self.chunk, file_index=self.file)
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = pq.ParquetWriter(path, self.schema)
        self.file_bytes += nbytes
        return self.writer

    def add(self, episode: Episode) -> None:
        """Append one episode's frames (its columns must match the features given)."""
        n, index = episode.length, len(self.rows)
        if n < 1:
            raise LeRobotFormatError(f"episode {index} has no frames")
        missing = set(self.features) - set(DEFAULT_FEATURES) - set(episode.columns)
        if missing or set(episode.columns) - set(self.features):
            raise LeRobotFormatError(f"episode {index}: columns {sorted(episode.columns)} do not match the "
                                     f"features {sorted(set(self.features) - set(DEFAULT_FEATURES))}")
        task = self.tasks.setdefault(episode.task, len(self.tasks))
        frame = np.arange(n, dtype=np.int64)
        columns = {**episode.columns, "timestamp": (frame / self.fps).astype(np.float32), "frame_index": frame,
                   "episode_index": np.full(n, index, np.int64), "index": self.frames + frame,
                   "task_index": np.full(n, task, np.int64)}
        for key, ft in self.features.items():
            want = (n, *ft["shape"]) if list(ft["shape"]) != [1] else (n,)
            got = columns[key].shape
            if got != want and not (list(ft["shape"]) == [1] and got == (n, 1)):
                raise LeRobotFormatError(f"episode {index}: {key} has shape {got}, expected {want}")
        table = pa.Table.from_arrays([_to_arrow(ft, columns[k]) for k, ft in self.features.items()],
                                     schema=self.schema)
        self._data_file(table.nbytes).write_table(table)
        chunk, file = self.chunk, self.file
        stats = {k: lerobot_stats.feature_stats(ft, columns[k].reshape(n, *ft["shape"]))
                 for k, ft in self.features.items()}
        self.stats.append(stats)
        self.rows.append({"episode_index": index, "tasks": [episode.task], "length": n,
                          "data/chunk_index": chunk, "data/file_index": file,
                          "dataset_from_index": self.frames, "dataset_to_index": self.frames + n,
                          "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                          **{f"stats/{k}/{name}": v.tolist() for k, s in stats.items() for name, v in s.items()},
                          **episode.meta})
        self.frames += n

    def finish(self) -> None:
        """Close the data file and write meta/: episodes, tasks, stats, info."""
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        if not self.rows:
            raise LeRobotFormatError("no episodes to write")
        meta = self.root / "meta"
        path = self.root / EPISODES_PATH.format(chunk_index=0, file_index=0)
        path.parent.mkdir(parents=True, exist_ok=True)
        columns = {k: pa.array([r.get(k) for r in self.rows], self.meta_types.get(k)) for k in self.rows[0]}
        pq.write_table(pa.table(columns), path)
        self._write_tasks(meta / "tasks.parquet")
        merged = {k: lerobot_stats.aggregate([s[k] for s in self.stats]) for k in self.features}
        (meta / "stats.json").write_text(json.dumps(lerobot_stats.to_json(merged), indent=2))
        info = {"codebase_version": CODEBASE_VERSION, "robot_type": self.robot_type, "repo_id": self.repo_id,
                "total_episodes": len(self.rows), "total_frames": self.frames, "total_tasks": len(self.tasks),
                "chunks_size": CHUNKS_SIZE, "data_files_size_in_mb": DATA_FILE_SIZE_MB,
                "video_files_size_in_mb": 500, "fps": self.fps, "splits": {"train": f"0:{len(self.rows)}"},
                "data_path": DATA_PATH, "video_path": None, "features": self.features}
        (meta / "info.json").write_text(json.dumps(info, indent=4))

    def _write_tasks(self, path: Path) -> None:
        """tasks.parquet as pandas writes lerobot's frame: task_index, indexed by the task string."""
        pandas_meta = {"index_columns": ["task"], "column_indexes": [], "creator": {"library": "pyarrow"},
                       "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
                                    "numpy_type": "int64", "metadata": None},
                                   {"name": "task", "field_name": "task", "pandas_type": "unicode",
                                    "numpy_type": "object", "metadata": None}]}
        schema = pa.schema([("task_index", pa.int64()), ("task", pa.string())],
                           metadata={"pandas": json.dumps(pandas_meta)})
        pq.write_table(pa.table([list(self.tasks.values()), list(self.tasks)], schema=schema), path)


@dataclass
class Dataset:
    """A v3.0 dataset's metadata, and its episodes read on demand."""

    root: Path
    info: dict
    tasks: dict[int, str]
    episodes: list[dict]  #: the episodes table's rows, by episode_index
    _cached: tuple[Path, pa.Table] | None = field(default=None, repr=False)  #: the last data file read

    @property
    def features(self) -> dict[str, dict]:
        return self.info["features"]

    def episode(self, i: int) -> Episode:
        """Episode ``i``'s frames (automatic features included) with its task and episodes-table row."""
        row = self.episodes[i]
        path = self.root / self.info["data_path"].format(chunk_index=int(row["data/chunk_index"]),
                                                         file_index=int(row["data/file_index"]))
        if self._cached is None or self._cached[0] != path:  # episodes in order share their files
            try:
                self._cached = (path, pq.read_table(path))
            except (OSError, pa.ArrowException) as e:
                raise LeRobotFormatError(f"{path}: unreadable data file ({e})") from None
        table = self._cached[1]
        table = table.filter(pc.equal(table["episode_index"], row["episode_index"]))
        if len(table) != int(row["length"]):
            raise LeRobotFormatError(f"{path}: episode {row['episode_index']} has {len(table)} frames, "
                                     f"the episodes table says {row['length']}")
        columns = {}
        for key, ft in self.features.items():
            if ft["dtype"] == "video":
                raise LeRobotFormatError(f"{key}: stored as video; this reader takes images embedded in the data")
            if key not in table.column_names:
                raise LeRobotFormatError(f"{path}: no column {key!r} although info.json declares it")
            columns[key] = _from_arrow(ft, table[key], key)
        tasks = row.get("tasks") or [self.tasks.get(int(columns["task_index"][0, 0]), "")]
        return Episode(task=tasks[0], columns=columns, meta=row)


def read_dataset(root: Path) -> Dataset:
    """Open a v3.0 dataset's metadata; LeRobotFormatError (one line) when it is none."""
    root = Path(root)
    try:
        info = json.loads((root / "meta" / "info.json").read_text())
    except FileNotFoundError:
        raise LeRobotFormatError(f"{root}: no meta/info.json: not a LeRobot dataset") from None
    except ValueError as e:
        raise LeRobotFormatError(f"{root}/meta/info.json: not JSON ({e})") from None
    version = str(info.get("codebase_version", ""))
    if not version.startswith("v3"):
        raise LeRobotFormatError(f"{root}: codebase_version {version or 'missing'}, this reader takes v3.x "
                                 "(convert with lerobot's convert_dataset_v21_to_v30)")
    try:
        task_table = pq.read_table(root / "meta" / "tasks.parquet").to_pylist()
        tasks = {int(t["task_index"]): str(t.get("task", t.get("__index_level_0__", ""))) for t in task_table}
        episodes = []
        for path in sorted((root / "meta" / "episodes").glob("*/*.parquet")):
            table = pq.read_table(path)
            keep = [c for c in table.column_names if not c.startswith("stats/")]
            episodes += table.select(keep).to_pylist()
    except (OSError, pa.ArrowException, KeyError) as e:
        raise LeRobotFormatError(f"{root}: unreadable meta/ ({type(e).__name__}: {e})") from None
    episodes.sort(key=lambda r: r["episode_index"])
    if not episodes:
        raise LeRobotFormatError(f"{root}: no episodes in meta/episodes/")
    return Dataset(root, info, tasks, episodes)
