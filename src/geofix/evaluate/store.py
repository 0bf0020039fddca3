"""The results store: one SQLite file, one row per (scenario, method, trial), and the summary.

Every finished trial is committed at once (write-ahead log), so a campaign that is killed
loses nothing and a rerun with the same output folder skips what is done. Rows are keyed
by the *scenario hash* (see :func:`scenario_hash`), so editing a scenario, its map or
geofix's own code never mixes old results with new ones.

Beside the ``trials`` table, the side table ``trial_bounds`` holds each trial's bounds
and true end point (:class:`~geofix.evaluate.bounds.TrialInfo`): one row per (scenario
hash, trial), its columns grown over versions (an older store gains the newer columns on
first use, :meth:`ResultStore.open_bounds`, and the rows it lacks them for are refilled
by the campaign). The campaign's summary is ``summary.json`` in the same folder
(:data:`SUMMARY_NAME`, :func:`write_summary`, :func:`read_summary`).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import math
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from geofix._atomic import write_text_atomic
from geofix.errors import ConfigError, GeofixError, MapError
from geofix.evaluate.bounds import TrialInfo
from geofix.evaluate.runner import TrialResult
from geofix.maps.bundled import BUILTIN_PREFIX, builtin_path
from geofix.sim.scenario import Scenario

STORE_NAME = "results.sqlite"
#: The campaign summary beside the store (:func:`write_summary`).
SUMMARY_NAME = "summary.json"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS trials (
    scenario TEXT NOT NULL,
    scenario_hash TEXT NOT NULL,
    method TEXT NOT NULL,
    trial INTEGER NOT NULL,
    end_error_m REAL,
    mean_track_error_m REAL,
    max_track_error_m REAL,
    leg_errors_m TEXT NOT NULL,
    time_s REAL NOT NULL,
    n_calls INTEGER NOT NULL,
    evaluations INTEGER NOT NULL,
    ambiguous INTEGER NOT NULL,
    failed INTEGER NOT NULL,
    message TEXT NOT NULL,
    covariance TEXT,
    estimate BLOB NOT NULL,
    error BLOB NOT NULL,
    PRIMARY KEY (scenario_hash, method, trial)
)
"""

#: Columns of :meth:`ResultStore.to_frame` without the per-sample arrays.
SCALAR_COLUMNS = (
    "scenario",
    "scenario_hash",
    "method",
    "trial",
    "end_error_m",
    "mean_track_error_m",
    "max_track_error_m",
    "leg_errors_m",
    "time_s",
    "n_calls",
    "evaluations",
    "ambiguous",
    "failed",
    "message",
)
_ARRAY_COLUMNS = ("covariance", "estimate", "error")
_COLUMNS = SCALAR_COLUMNS + _ARRAY_COLUMNS

_BOUNDS_SCHEMA = """
CREATE TABLE IF NOT EXISTS trial_bounds (
    scenario_hash TEXT NOT NULL,
    trial INTEGER NOT NULL,
    crlb_var_m2 REAL,
    crlb_batch_var_m2 REAL,
    truth_end_x REAL NOT NULL,
    truth_end_y REAL NOT NULL,
    crlb_track_var_m2 REAL,
    crlb_rw_var_m2 REAL,
    valid_track_m2 BLOB,
    genie_track_m2 BLOB,
    PRIMARY KEY (scenario_hash, trial)
)
"""
#: Columns of ``trial_bounds`` added after its first version, with their SQL types.
_BOUNDS_ADDED = {
    "crlb_track_var_m2": "REAL",
    "crlb_rw_var_m2": "REAL",
    "valid_track_m2": "BLOB",
    "genie_track_m2": "BLOB",
}
_BOUNDS_COLUMNS = (
    *("scenario_hash", "trial", "crlb_var_m2", "crlb_batch_var_m2"),
    *("truth_end_x", "truth_end_y", *_BOUNDS_ADDED),
)
#: Longest time recorded results wait for their commit, seconds (:class:`Batches`).
COMMIT_INTERVAL_S = 0.05


def scenario_hash(scenario: Scenario) -> str:
    """A fingerprint of everything that decides a scenario's trials.

    Parameters
    ----------
    scenario : Scenario
        The scenario. Its ``trials`` count is left out (trial ``i`` does not depend on how
        many trials are run, so a longer campaign extends a shorter one), as is
        ``base_dir``.

    Returns
    -------
    str
        Hex SHA-256 of the canonical JSON of the scenario plus the SHA-256 of the map
        file's content (:func:`file_digest`) and of geofix's own code
        (:func:`code_digest`): a map replaced by other values of the same size, or a
        method changed since the results were stored, gives another hash, so stale
        results are never returned.

    Raises
    ------
    MapError
        If the map file does not exist.
    """
    data = scenario.model_dump(mode="json", exclude={"base_dir", "trials"})
    path = _map_file(scenario)
    data["_map_file"] = {"name": path.name, "sha256": file_digest(path)}
    data["_code"] = code_digest()
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


_DIGESTS: dict[tuple[str, int, int], str] = {}


@functools.cache
def code_digest() -> str:
    """SHA-256 of geofix's own Python source, read once per process.

    Every ``.py`` file of the installed package, in the order of their paths relative to
    it, each path beside its content: a campaign's stored trials belong to the code that
    ran them, and a store written by other code is not read as this code's.

    Returns
    -------
    str
        Hex SHA-256.
    """
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode("utf-8") + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's content, cached by (resolved path, mtime, size) in this process.

    Raises
    ------
    MapError
        If the file does not exist or cannot be read.
    """
    path = Path(path)
    try:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
        if key not in _DIGESTS:
            with open(path, "rb") as f:
                _DIGESTS[key] = hashlib.file_digest(f, "sha256").hexdigest()
    except FileNotFoundError:
        raise MapError(f"map file not found: {path}") from None
    except OSError as exc:
        raise MapError(f"cannot read map file {path}: {exc.strerror or exc}") from None
    return _DIGESTS[key]


def _map_file(scenario: Scenario) -> Path:
    if scenario.map.path.startswith(BUILTIN_PREFIX):
        return builtin_path(scenario.map.path)
    return Path(scenario.map_path())


@contextlib.contextmanager
def store_errors(path: str | Path) -> Iterator[None]:
    """Turn an SQLite error inside the block into one GeofixError naming the store.

    A full disk (``database or disk is full``), a corrupted page (``database disk image
    is malformed``) or a locked store ends the command with the path and the reason;
    trials committed before it stay in the store.
    """
    try:
        yield
    except sqlite3.Error as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise GeofixError(f"results store {path}: {reason}") from None


class ResultStore:
    """Trial results in ``<out_dir>/results.sqlite``.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Output folder; created if missing.
    """

    def __init__(self, out_dir: str | Path) -> None:
        self.path = Path(out_dir) / STORE_NAME
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.execute(_SCHEMA)
            self._db.commit()
            columns = [row[1] for row in self._db.execute("PRAGMA table_info(trials)")]
        except (OSError, sqlite3.Error) as exc:
            raise GeofixError(f"cannot open results store {self.path}: {exc}") from None
        if columns != list(_COLUMNS):
            self._db.close()
            raise GeofixError(
                f"{self.path} is not a geofix results store (its 'trials' table has columns "
                f"{', '.join(columns)}); choose another --out"
            )

    def close(self) -> None:
        """Close the database connection."""
        self._db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def connection(self) -> sqlite3.Connection:
        """The store's SQLite connection (side tables of the layers above share it)."""
        return self._db

    def commit(self) -> None:
        """Commit the results recorded with ``commit=False`` since the last commit."""
        self._db.commit()

    def record(
        self,
        scenario: str,
        shash: str,
        method: str,
        trial: int,
        result: TrialResult,
        commit: bool = True,
    ) -> None:
        """Write (or overwrite) one trial's result; commit at once unless told not to.

        Parameters
        ----------
        scenario : str
            Scenario name.
        shash : str
            Scenario hash (:func:`scenario_hash`).
        method : str
            Method specification string, exactly as given.
        trial : int
            Trial number.
        result : TrialResult
            The outcome (errors in metres, time in seconds).
        commit : bool
            False leaves the row in the open transaction until :meth:`commit` (a campaign
            of quick trials commits a batch at a time: a commit costs as much as a trial).
        """
        row = _row(scenario, shash, method, trial, result)
        marks = ",".join("?" * len(row))
        self._db.execute(f"INSERT OR REPLACE INTO trials VALUES ({marks})", row)
        if commit:
            self._db.commit()

    def open_bounds(self) -> None:
        """Create the ``trial_bounds`` side table if missing; add the columns it lacks.

        Raises
        ------
        GeofixError
            The store cannot be written.
        """
        try:
            self._db.execute(_BOUNDS_SCHEMA)
            have = self._bounds_columns()
            for column, kind in _BOUNDS_ADDED.items():
                if column not in have:  # a store of an earlier version: its rows are refilled
                    self._db.execute(f"ALTER TABLE trial_bounds ADD COLUMN {column} {kind}")
            self._db.commit()
        except sqlite3.Error as exc:
            raise GeofixError(f"cannot open results store {self.path}: {exc}") from None

    def _bounds_columns(self) -> list[str]:
        return [row[1] for row in self._db.execute("PRAGMA table_info(trial_bounds)")]

    def record_bounds(self, shash: str, info: TrialInfo, commit: bool = True) -> None:
        """Write (or overwrite) one trial's bounds (:meth:`open_bounds` first).

        Valid-bound terms the ``info`` lacks keep their stored values.

        Parameters
        ----------
        shash : str
            Scenario hash (:func:`scenario_hash`).
        info : TrialInfo
            The trial's bounds (m^2) and true end point (metres).
        commit : bool
            False leaves the row in the open transaction until :meth:`commit`.
        """
        row = (
            shash,
            info.index,
            info.crlb_var_m2,
            info.crlb_batch_var_m2,
            *info.truth_end,
            info.crlb_track_var_m2,
            info.crlb_rw_var_m2,
            _array_blob(info.valid_track_m2),
            _array_blob(info.genie_track_m2),
        )
        keep = ("valid_track_m2", "genie_track_m2")
        update = ", ".join(
            f"{c} = COALESCE(excluded.{c}, {c})" if c in keep else f"{c} = excluded.{c}"
            for c in _BOUNDS_COLUMNS[2:]
        )
        self._db.execute(
            f"INSERT INTO trial_bounds ({', '.join(_BOUNDS_COLUMNS)}) "
            f"VALUES ({', '.join('?' * len(row))}) "
            f"ON CONFLICT (scenario_hash, trial) DO UPDATE SET {update}",
            row,
        )
        if commit:
            self._db.commit()

    def trial_bounds(self, shash: str) -> dict[int, TrialInfo]:
        """The stored bounds of scenario hash ``shash``'s trials, by trial number.

        Values a store of an earlier version lacks are NaN (the valid-bound terms None);
        a store without the ``trial_bounds`` table gives ``{}``.
        """
        try:
            have = set(self._bounds_columns())
            if not have:
                return {}
            columns = [c if c in have else "NULL" for c in _BOUNDS_COLUMNS[1:]]
            cur = self._db.execute(
                f"SELECT {', '.join(columns)} FROM trial_bounds WHERE scenario_hash = ?",
                (shash,),
            )
            rows = cur.fetchall()
        except sqlite3.Error:
            return {}
        return {int(row[0]): _trial_info(row) for row in rows}

    def done_keys(self, shash: str) -> set[tuple[str, int]]:
        """``(method, trial)`` pairs already stored for scenario hash ``shash``."""
        cur = self._db.execute("SELECT method, trial FROM trials WHERE scenario_hash = ?", (shash,))
        return {(m, int(t)) for m, t in cur}

    def to_frame(self, shash: str | None = None, arrays: bool = False) -> pd.DataFrame:
        """The stored rows as a DataFrame, sorted by scenario hash, method and trial.

        Parameters
        ----------
        shash : str, optional
            Keep only this scenario hash.
        arrays : bool
            Also decode ``covariance`` ``(2, 2)`` m^2, ``estimate`` ``(n, 2)`` metres and
            ``error`` ``(n,)`` metres into numpy arrays per row.

        Returns
        -------
        pandas.DataFrame
            Columns :data:`SCALAR_COLUMNS` (``leg_errors_m`` holds a list of floats per
            row, NaN for a leg not reached), plus the array columns when asked.
        """
        columns = SCALAR_COLUMNS + (_ARRAY_COLUMNS if arrays else ())
        query = f"SELECT {', '.join(columns)} FROM trials"
        params: tuple = ()
        if shash is not None:
            query += " WHERE scenario_hash = ?"
            params = (shash,)
        query += " ORDER BY scenario_hash, method, trial"
        frame = pd.DataFrame(self._db.execute(query, params).fetchall(), columns=list(columns))
        return _decode(frame, arrays)

    def export(self, path: str | Path, shash: str | None = None) -> Path:
        """Write the table to ``.parquet`` or ``.csv`` (chosen by the suffix of ``path``).

        Per-sample arrays are included: in Parquet as list columns ``estimate_x``,
        ``estimate_y`` and ``error`` (metres); in CSV as JSON lists.

        Raises
        ------
        GeofixError
            If the suffix is neither ``.parquet`` nor ``.csv``.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".parquet", ".csv"):
            raise GeofixError(f"cannot export results to {path.name}: use .parquet or .csv")
        frame = _flatten_arrays(self.to_frame(shash, arrays=True))
        if suffix == ".parquet":
            frame.to_parquet(path, index=False)
        else:
            for col in ("leg_errors_m", "covariance", "estimate_x", "estimate_y", "error"):
                frame[col] = [json.dumps(_json_list(v)) for v in frame[col]]
            frame.to_csv(path, index=False)
        return path


class Batches:
    """Commit a store's open transaction every :data:`COMMIT_INTERVAL_S`, and on exit.

    A commit is not free in the calling process (which shares the cores with the
    workers), so results are committed in batches; a campaign killed outright loses at
    most this much work, which a rerun does again. On exit the batch is committed
    whatever ends the loop (the last result, Ctrl-C, a worker that died), so nothing
    recorded is lost.

    Parameters
    ----------
    store : ResultStore
        The store whose results are recorded with ``commit=False``.
    """

    def __init__(self, store: ResultStore) -> None:
        self.store = store
        self.last = time.perf_counter()

    def recorded(self) -> None:
        """Results were recorded: commit them if the last commit is old enough."""
        now = time.perf_counter()
        if now - self.last >= COMMIT_INTERVAL_S:
            self.store.commit()
            self.last = now

    def __enter__(self) -> Batches:
        return self

    def __exit__(self, *exc) -> None:
        self.store.commit()


def write_summary(out_dir: str | Path, summary: dict) -> Path:
    """Write a campaign's summary (its JSON object) to ``out_dir/summary.json``.

    Written to a temporary name and renamed: whole or absent, a report never reads half.
    Returns the path.
    """
    path = Path(out_dir) / SUMMARY_NAME
    text = json.dumps(summary, indent=2, allow_nan=False) + "\n"
    write_text_atomic(path, text)
    return path


def read_summary(out_dir: str | Path) -> dict:
    """The JSON object of ``out_dir/summary.json``.

    Raises
    ------
    ConfigError
        The file is missing, unreadable, not JSON or not a JSON object.
    """
    path = Path(out_dir) / SUMMARY_NAME
    if not path.is_file():
        raise ConfigError(f"no campaign summary {path} (run `geofix run --out {path.parent}`)")
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:
        reason = "nested too deeply" if isinstance(exc, RecursionError) else exc
        raise ConfigError(f"cannot read campaign summary {path}: {reason}") from None
    if not isinstance(summary, dict):
        raise ConfigError(f"campaign summary {path} is not a JSON object")
    return summary


def _trial_info(row: tuple) -> TrialInfo:
    """A :class:`TrialInfo` from a ``trial_bounds`` row (without the scenario hash)."""
    t, v, b, x, y, tr, rw, valid, genie = row
    return TrialInfo(
        int(t),
        _nan(v),
        _nan(b),
        (float(x), float(y)),
        _nan(tr),
        _nan(rw),
        _blob_array(valid),
        _blob_array(genie),
    )


def _nan(value) -> float:
    return float("nan") if value is None else float(value)


def _array_blob(values) -> bytes | None:
    return None if values is None else np.ascontiguousarray(values, dtype="<f8").tobytes()


def _blob_array(blob) -> np.ndarray | None:
    return None if blob is None else np.frombuffer(blob, dtype="<f8").copy()


def _row(scenario: str, shash: str, method: str, trial: int, r: TrialResult) -> tuple:
    cov = None if r.covariance is None else json.dumps(_json_list(r.covariance))
    return (
        scenario,
        shash,
        method,
        int(trial),
        _real(r.end_error_m),
        _real(r.mean_track_error_m),
        _real(r.max_track_error_m),
        json.dumps(_json_list(r.leg_errors_m)),
        float(r.time_s),
        int(r.n_calls),
        int(r.evaluations),
        int(bool(r.ambiguous)),
        int(bool(r.failed)),
        r.message,
        cov,
        np.ascontiguousarray(r.estimate, dtype="<f8").tobytes(),
        np.ascontiguousarray(r.error, dtype="<f8").tobytes(),
    )


def _decode(frame: pd.DataFrame, arrays: bool) -> pd.DataFrame:
    for col in ("end_error_m", "mean_track_error_m", "max_track_error_m"):
        frame[col] = frame[col].astype(float)
    frame["leg_errors_m"] = [_float_list(json.loads(v)) for v in frame["leg_errors_m"]]
    frame["ambiguous"] = frame["ambiguous"].astype(bool)
    frame["failed"] = frame["failed"].astype(bool)
    if arrays:
        frame["covariance"] = [
            np.array(_float_list(json.loads(v))) if isinstance(v, str) else None
            for v in frame["covariance"]
        ]
        frame["estimate"] = [
            np.frombuffer(b, dtype="<f8").reshape(-1, 2) for b in frame["estimate"]
        ]
        frame["error"] = [np.frombuffer(b, dtype="<f8") for b in frame["error"]]
    return frame


def _flatten_arrays(frame: pd.DataFrame) -> pd.DataFrame:
    frame = frame.copy()
    frame["estimate_x"] = [e[:, 0].tolist() for e in frame["estimate"]]
    frame["estimate_y"] = [e[:, 1].tolist() for e in frame["estimate"]]
    frame["error"] = [e.tolist() for e in frame["error"]]
    frame["covariance"] = [
        None if c is None else c.reshape(-1).tolist() for c in frame["covariance"]
    ]
    return frame.drop(columns=["estimate"])


def _real(value: float) -> float | None:
    value = float(value)
    return None if math.isnan(value) else value


def _json_list(values) -> list | None:
    """Nested lists of floats with NaN as None (strict JSON)."""
    if values is None:
        return None
    arr = np.asarray(values, dtype=float)
    out = arr.astype(object)
    out[np.isnan(arr)] = None
    return out.tolist()


def _float_list(values) -> list:
    """Back from :func:`_json_list`: None -> NaN, nested lists kept."""
    return np.asarray(values, dtype=float).tolist()
