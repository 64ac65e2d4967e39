"""Model registry, experiment log and diagnostic events of the historian (small tables
written and read through SQLAlchemy; mixed into :class:`historian.store.Historian`)."""

from __future__ import annotations

import json

import pandas as pd

from .lazy import LazyModule
from .quality import GOOD
from .times import from_us, now_us, to_us

sa = LazyModule("sqlalchemy")
schema = LazyModule("historian.schema")


class Registry:
    """Model versions, experiments and diagnostic events. Needs ``self.engine`` and
    ``self._writing()`` (a write transaction)."""

    # -- model registry and experiment log -----------------------------------------------
    def record_model_version(
        self, name: str, version: str, rulebase_text: str | None = None, created_at=None
    ) -> int:
        """Store a model version (its rule-base text); returns its id. Re-recording the same
        (name, version) replaces the text."""
        t = schema.model_versions
        at = to_us(created_at) if created_at is not None else now_us()
        with self._writing() as c:
            row = c.execute(
                sa.select(t.c.id).where(t.c.name == name, t.c.version == str(version))
            ).first()
            if row is not None:
                c.execute(sa.update(t).where(t.c.id == row[0]).values(rulebase_text=rulebase_text))
                return int(row[0])
            res = c.execute(
                sa.insert(t).values(
                    name=name, version=str(version), rulebase_text=rulebase_text, created_at=at
                )
            )
            return int(res.inserted_primary_key[0])

    def model_versions(self, name: str | None = None) -> pd.DataFrame:
        t = schema.model_versions
        q = sa.select(t).order_by(t.c.name, t.c.created_at, t.c.id)
        if name is not None:
            q = q.where(t.c.name == name)
        with self.engine.connect() as c:
            frame = pd.DataFrame(c.execute(q).all(), columns=[col.name for col in t.columns])
        frame["created_at"] = _ts_column(frame["created_at"])
        return frame

    def record_experiment(
        self,
        model: str,
        version: str | None,
        inputs: list[str],
        data_from,
        data_to,
        metrics: dict,
        *,
        notes: str | None = None,
        created_at=None,
    ) -> int:
        """Log a training/validation run; returns its id."""
        t = schema.experiments
        with self._writing() as c:
            res = c.execute(
                sa.insert(t).values(
                    model=model,
                    version=None if version is None else str(version),
                    inputs=json.dumps(list(inputs)),
                    data_from=to_us(data_from) if data_from is not None else None,
                    data_to=to_us(data_to) if data_to is not None else None,
                    metrics=json.dumps(metrics, sort_keys=True, default=float),
                    notes=notes,
                    created_at=to_us(created_at) if created_at is not None else now_us(),
                )
            )
            return int(res.inserted_primary_key[0])

    def experiments(self, model: str | None = None) -> pd.DataFrame:
        """Experiments (oldest first): id, model, version, inputs (list), data_from, data_to,
        metrics (dict), notes, created_at."""
        t = schema.experiments
        q = sa.select(t).order_by(t.c.created_at, t.c.id)
        if model is not None:
            q = q.where(t.c.model == model)
        with self.engine.connect() as c:
            frame = pd.DataFrame(c.execute(q).all(), columns=[col.name for col in t.columns])
        frame["inputs"] = [json.loads(x) for x in frame["inputs"]]
        frame["metrics"] = [json.loads(x) for x in frame["metrics"]]
        for col in ("data_from", "data_to", "created_at"):
            frame[col] = _ts_column(frame[col])
        return frame

    # -- diagnostic events ---------------------------------------------------------------
    def record_event(
        self,
        ts,
        unit: str,
        *,
        fault: str | None = None,
        status: int = 0,
        certainty: float | None = None,
        severity: int | None = None,
        quality: int = GOOD,
        message: str | None = None,
    ) -> int:
        """Store one diagnosis (NE 107 ``status``, fault ``certainty``); returns its id."""
        t = schema.diag_events
        with self._writing() as c:
            res = c.execute(
                sa.insert(t).values(
                    ts=to_us(ts),
                    unit=unit,
                    fault=fault,
                    status=int(status),
                    certainty=certainty,
                    severity=severity,
                    quality=int(quality),
                    message=message,
                )
            )
            return int(res.inserted_primary_key[0])

    def events(self, unit: str | None = None, start=None, end=None) -> pd.DataFrame:
        t = schema.diag_events
        q = sa.select(t).order_by(t.c.ts, t.c.id)
        if unit is not None:
            q = q.where(t.c.unit == unit)
        if start is not None:
            q = q.where(t.c.ts >= to_us(start))
        if end is not None:
            q = q.where(t.c.ts < to_us(end))
        with self.engine.connect() as c:
            frame = pd.DataFrame(c.execute(q).all(), columns=[col.name for col in t.columns])
        frame["ts"] = _ts_column(frame["ts"])
        return frame


def _ts_column(col: pd.Series) -> pd.Series:
    vals = pd.array(col, dtype="Int64")
    return pd.Series(
        [from_us(v) if v is not pd.NA else pd.NaT for v in vals],
        index=col.index,
        dtype="datetime64[us, UTC]",
    )
