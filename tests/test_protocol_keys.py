"""Key expressions are never built from unchecked text, and never publish on a wildcard."""

from __future__ import annotations

import pytest

from protocol import keys

BAD_IDS = ["a/b", "$*", "a*", "a b", "a\tb", "a\n", "a?", "a#b", "", "x" * 65, "..", "-x", None, 3]


def test_keys_of_a_run():
    assert keys.episodes("run-1", "actor-0") == "c2farm/run-1/episodes/actor-0"
    assert keys.acks("run-1", "actor-0") == "c2farm/run-1/acks/actor-0"
    assert keys.weights("run-1") == "c2farm/run-1/weights"
    assert keys.status("run-1", "actor", "actor-0") == "c2farm/run-1/status/actor/actor-0"
    assert keys.alive("run-1", "actor", "actor-0") == "c2farm/run-1/alive/actor/actor-0"


def test_subscribers_ask_for_wildcards_explicitly():
    assert keys.episodes("run-1") == "c2farm/run-1/episodes/*"
    assert keys.status("run-1") == "c2farm/run-1/status/*/*"
    assert keys.alive("run-1", "**", "**") == "c2farm/run-1/alive/**/**"


@pytest.mark.parametrize("bad", BAD_IDS, ids=repr)
def test_every_builder_rejects_bad_text(bad):
    for build in (
        lambda: keys.weights(bad),
        lambda: keys.episodes(bad, "actor-0"),
        lambda: keys.episodes("run-1", bad),
        lambda: keys.acks("run-1", bad),
        lambda: keys.status("run-1", bad, "actor-0"),
        lambda: keys.alive("run-1", "actor", bad),
        lambda: keys.check_id(bad),
    ):
        with pytest.raises(ValueError):
            build()


def test_wildcards_only_where_a_subscriber_may_use_them():
    for build in (lambda: keys.weights("*"), lambda: keys.acks("*", "a"), lambda: keys.episodes("run-1", "**")):
        with pytest.raises(ValueError):
            build()


def test_a_publisher_key_must_be_concrete():
    assert keys.concrete(keys.acks("run-1", "actor-0")) == "c2farm/run-1/acks/actor-0"
    for wide in (keys.acks("run-1"), keys.status("run-1"), "c2farm/r/$*", "c2farm/r/a b"):
        with pytest.raises(ValueError):
            keys.concrete(wide)


def test_role_keys_parse_only_into_valid_ids():
    assert keys.parse_role_instance("c2farm/run-1/status/actor/actor-0") == ("actor", "actor-0")
    for key in ("c2farm/run-1/status/actor", "other/run-1/status/actor/a", "c2farm/run-1/status/*/a",
                "c2farm/run-1/status/actor/a b"):
        with pytest.raises(ValueError):
            keys.parse_role_instance(key)
