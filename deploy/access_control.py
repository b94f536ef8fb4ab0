"""The router's access rules: each certificate may do what its role does, on its own keys, and nothing else.

Zenoh judges every message at the router by the common name of the TLS certificate it came
over (``role.instance``, see ``deploy/certs.py``), default deny. What each role may do, with
``P = c2farm/<run>``:

- every process: put its heartbeat on ``P/status/<role>/<instance>`` and hold its liveliness
  token ``P/alive/<role>/<instance>``; nothing under another name;
- learner: publish ``P/weights`` and answer queries on it;
- actor, robot, eval (weights followers): receive ``P/weights`` and the learner's status, and
  query ``P/weights`` (a querier needs ``reply`` on egress, or its ``get`` gets nothing);
- actor, robot, demo_source (episode senders): put only on ``P/episodes/<instance>`` and
  receive only ``P/acks/<instance>``;
- robot: receive its own ``P/operator/<instance>``;
- replay: receive ``P/episodes/*``, put ``P/acks/*``, watch the actors' liveliness;
- dashboard: receive every status and liveliness token, put operator commands.

Known traps, handled here or in the tests: a denied put is dropped silently (no error to the
publisher), so tests assert on the receiving side; common names match exactly (no globs), so
the subjects list every certificate the router found; and Zenoh reads these rules once, so a
certificate added later needs a router restart.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Iterable

from deploy.certs import SEPARATOR, role_of

#: (flow, message kinds) of each thing a role does on a key. Ingress is what a client sends to the
#: router, egress what the router passes on to it: receiving a put is an egress ``put``, so a
#: subscriber is never also allowed to publish on the key it reads.
Grant = tuple[tuple[str, tuple[str, ...]], ...]
RECEIVE: Grant = (("ingress", ("declare_subscriber",)), ("egress", ("put", "delete")))
SEND: Grant = (("ingress", ("put", "delete")),)
QUERY: Grant = (("ingress", ("query",)), ("egress", ("reply",)))
ANSWER: Grant = (("ingress", ("declare_queryable", "reply")), ("egress", ("query",)))
WATCH: Grant = (("ingress", ("declare_liveliness_subscriber", "liveliness_query")),
                ("egress", ("liveliness_token", "reply")))
OWN_TOKEN: Grant = (("ingress", ("liveliness_token",)),)
#: A declared publisher sends only once the router has told it of a matching subscriber
#: (write-side filtering), and a subscriber's declaration is judged by its own key expression
#: (``P/status/*/*``), which no single sender's key includes. So every process may hear which
#: subscribers and queryables exist in the run: their key expressions, never data.
DISCOVER: Grant = (("egress", ("declare_subscriber", "declare_queryable", "declare_liveliness_subscriber")),)

WEIGHT_FOLLOWERS = ("actor", "robot", "eval")
EPISODE_SENDERS = ("actor", "robot", "demo_source")


def access_control(run_id: str, names: Iterable[str]) -> dict:
    """Zenoh's ``access_control`` section for the certificates ``names`` of run ``run_id``."""
    p = f"c2farm/{run_id}"
    rules: list[dict] = []
    policies: list[dict] = []
    subjects: list[dict] = []
    for n, name in enumerate(sorted(set(names))):
        role, _, instance = name.partition(SEPARATOR)
        grants: dict[Grant, set[str]] = defaultdict(set)
        grants[SEND] |= {f"{p}/status/{role}/{instance}"}
        grants[OWN_TOKEN] |= {f"{p}/alive/{role}/{instance}"}
        grants[DISCOVER] |= {f"{p}/**"}
        if role == "learner":
            grants[SEND] |= {f"{p}/weights"}
            grants[ANSWER] |= {f"{p}/weights"}
        if role in WEIGHT_FOLLOWERS:
            grants[RECEIVE] |= {f"{p}/weights", f"{p}/status/learner/*"}
            grants[QUERY] |= {f"{p}/weights"}
        if role in EPISODE_SENDERS:
            grants[SEND] |= {f"{p}/episodes/{instance}"}
            grants[RECEIVE] |= {f"{p}/acks/{instance}"}
        if role == "robot":
            grants[RECEIVE] |= {f"{p}/operator/{instance}"}
        if role == "replay":
            grants[RECEIVE] |= {f"{p}/episodes/*"}
            grants[SEND] |= {f"{p}/acks/*"}
            grants[WATCH] |= {f"{p}/alive/actor/*", f"{p}/alive/robot/*", f"{p}/alive/demo_source/*"}
        if role == "dashboard":
            grants[RECEIVE] |= {f"{p}/status/**"}
            grants[WATCH] |= {f"{p}/alive/**"}
            grants[SEND] |= {f"{p}/operator/*"}
        ids = []
        for grant, key_exprs in sorted(grants.items()):
            for flow, messages in grant:
                rule_id = f"s{n}r{len(ids)}"
                rules.append({"id": rule_id, "permission": "allow", "flows": [flow], "messages": list(messages),
                              "key_exprs": sorted(key_exprs)})
                ids.append(rule_id)
        subjects.append({"id": f"s{n}", "cert_common_names": [name]})
        policies.append({"id": f"s{n}p", "rules": ids, "subjects": [f"s{n}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def unknown_roles(names: Iterable[str]) -> list[str]:
    """Certificate names whose role part is not one of ours (they get no rights at all)."""
    from deploy.roles import ROLES

    return [n for n in names if role_of(n) not in ROLES]
