"""``/metrics``: the role table as Prometheus families, through ``prometheus_client``.

The library does the exposition format (escaping, ``NaN``/``+Inf``, one TYPE line per family);
:mod:`dashboard.metrics_catalog` says what each role counter is. The collector reads a
:class:`~dashboard.registry.RoleTable` snapshot per scrape and lives in a private
``CollectorRegistry``: nothing lands in the process-global default registry, so two apps
(tests) never see each other's series.
"""

from __future__ import annotations

import logging
import threading
from typing import Callable, Iterator

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from dashboard.metrics_catalog import Family, lookup

log = logging.getLogger(__name__)

#: the exposition format generate_latest writes (legacy names, no UTF-8 escaping needed)
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
UNDOCUMENTED = "c2farm_undocumented"
_ROLE_LABELS = ["run", "role", "instance"]


class RoleTableCollector(Collector):
    """Yields the families of one snapshot of the role table; logs each uncatalogued counter once."""

    def __init__(self, snapshot: Callable[[], dict]):
        self._snapshot = snapshot
        self._lock = threading.Lock()
        self._warned: set[tuple[str, str]] = set()

    def collect(self) -> Iterator[Metric]:
        snap = self._snapshot()
        run = str(snap["run_id"])
        alive = GaugeMetricFamily("c2farm_role_alive", "1 while a role instance is alive, 0 once gone.",
                                  labels=_ROLE_LABELS)
        age = GaugeMetricFamily("c2farm_role_last_seen_age_seconds",
                                "Seconds since a role instance was last heard from.", labels=_ROLE_LABELS)
        undocumented = GaugeMetricFamily(
            UNDOCUMENTED, "A role counter missing from dashboard/metrics_catalog.py, exported as reported "
            "(type and unit unknown; the name label is the counter's name).", labels=[*_ROLE_LABELS, "name"])
        built: dict[str, Metric] = {}
        for r in snap["roles"]:
            who = [run, str(r["role"]), str(r["instance"])]
            alive.add_metric(who, int(r["alive"]))
            if r["last_seen_age_s"] is not None:
                age.add_metric(who, float(r["last_seen_age_s"]))
            for name, value in sorted(r["counters"].items()):
                found = lookup(who[1], name)
                if found is None:
                    self._warn_once(who[1], name)
                    undocumented.add_metric([*who, name], float(value))
                    continue
                entry, label = found
                if isinstance(entry, Family):
                    if entry.name not in built:
                        built[entry.name] = _new(entry)
                    built[entry.name].add_metric(who + ([label] if entry.label else []), float(value) * entry.scale)
        yield alive
        yield age
        rejected = CounterMetricFamily("c2farm_rejected_status_messages_total",
                                       "Malformed status messages the dashboard rejected.", labels=["run"])
        rejected.add_metric([run], float(snap["rejected_messages"]))
        yield rejected
        yield from (built[name] for name in sorted(built))
        if undocumented.samples:
            yield undocumented

    def _warn_once(self, role: str, name: str) -> None:
        with self._lock:
            if (role, name) in self._warned:
                return
            self._warned.add((role, name))
        log.warning("role %s reports counter %r, which dashboard/metrics_catalog.py does not describe: "
                    "exported as %s{name=%r}", role, name, UNDOCUMENTED, name)


def _new(family: Family) -> Metric:
    labels = [*_ROLE_LABELS, *([family.label] if family.label else [])]
    cls = CounterMetricFamily if family.kind == "counter" else GaugeMetricFamily
    return cls(family.name, family.help, labels=labels)


def metrics_registry(snapshot: Callable[[], dict]) -> CollectorRegistry:
    """A private registry holding one :class:`RoleTableCollector` over ``snapshot``."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(RoleTableCollector(snapshot))
    return registry


def prometheus_text(snapshot: dict) -> str:
    """One snapshot in Prometheus text format (what ``GET /metrics`` answers)."""
    return generate_latest(metrics_registry(lambda: snapshot)).decode()
