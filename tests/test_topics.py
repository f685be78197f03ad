"""The pipeline's graph (common/msgs/topics.py) is the one declaration of the bus: every key a
service puts on, listens to, asks or answers is declared there with that service in the right
role, the recorder's and the validation's tables come from it, and the README prints it."""

import re
from pathlib import Path

import pytest

from common.msgs import TOPICS, ServiceStatus
from common.msgs.topics import GRAPH, SERVICES, table, topic
from common.validation import SPEAKERS, speakers

ROOT = Path(__file__).resolve().parents[1]
KEY = r'bus\.key\("([^"]*)"\)'
ROLES = {  # how a service file uses a key -> the role the graph must give that service
    rf"publisher\(\s*[\w.]+,\s*[\w.]*{KEY}": "publishers",
    rf"declare_queryable\({KEY}": "publishers",
    rf"declare_subscriber\({KEY}": "subscribers",
    rf"declare_querier\({KEY}": "subscribers",
    rf"FrameImages\(\s*[\w.]+,\s*{KEY}": "subscribers",
    rf"declare_token\({KEY}": "publishers",
    r'\.subscribe\("([^"]*)"': "subscribers",  # services.bus.ServiceShell
    r'\.queryable\("([^"]*)"': "publishers",
    r'\.publisher\("([^"]*)"': "publishers",
}


def uses(text: str) -> list[tuple[str, str]]:
    """(key, role) of every literal key a module publishes, answers, subscribes to or asks."""
    return [(m.group(1), role) for pattern, role in ROLES.items() for m in re.finditer(pattern, text)]


def misdeclared(service: str, text: str) -> list[str]:
    out = []
    for key, role in uses(text):
        t = topic(key.replace("/*", "/x")) if key.endswith("/*") else topic(key)
        if key in ("**", ""):
            continue  # the recorder: everything, filtered by the graph (recorded keys)
        if t is None:
            out.append(f"{service}: {key} is not declared")
        elif service not in getattr(t, role):
            out.append(f"{service}: {role[:-1]} of {key}, the graph says {getattr(t, role)}")
    return out


@pytest.mark.parametrize("service", [*SERVICES, "launcher"])
def test_every_key_a_service_uses_is_declared_with_its_role(service):
    text = (ROOT / "services" / f"{service}.py").read_text()
    assert uses(text) or ".alive()" in text or service in ("router", "launcher")
    assert misdeclared(service, text) == []
    if "shell.alive()" in text or "service.alive()" in text:  # ServiceShell.alive: its status, health and token
        for key in ("status/<service>", "health/<service>", "alive/<service>"):
            assert service in topic(key.replace("<service>", service)).publishers


def test_the_viewer_listens_to_what_the_graph_says():
    from services.viewer import SUBSCRIPTIONS

    for key in SUBSCRIPTIONS:
        t = topic(key.replace("/*", "/viewer"))
        assert t is not None and "viewer" in t.subscribers, key
    heard = {t.key for t in GRAPH if "viewer" in t.subscribers}
    assert heard == {k.replace("/*", "/<service>") for k in SUBSCRIPTIONS}


def test_a_key_used_but_not_declared_or_in_the_wrong_role_is_found():
    """Negative controls of the check above."""
    text = 'pub = publisher(session, bus.key("track/secret"))\nsub = session.declare_subscriber(bus.key("frame/info"), cb)\n'
    assert misdeclared("detector", text) == ["detector: track/secret is not declared",
                                             "detector: subscriber of frame/info, the graph says "
                                             "('tracker', 'recorder', 'viewer', 'launcher')"]
    shell_text = 'shell.subscribe("run/config", cb)\nshell.publisher("frame/image")\n'
    assert misdeclared("tracker", shell_text) == [
        "tracker: subscriber of run/config, the graph says ('recorder', 'viewer')",
        "tracker: publisher of frame/image, the graph says ('ingest',)"]


def test_the_tables_derived_from_the_graph():
    recorded = {t.key for t in GRAPH if t.recorded and "<service>" not in t.key}
    assert set(TOPICS) == recorded and TOPICS["track/annotations"].DESCRIPTOR.full_name == "foxglove.ImageAnnotations"
    assert topic("status/tracker").message is ServiceStatus and topic("status/a/b") is None and topic("nope") is None
    assert speakers("track/estimate") == ("tracker",) and speakers("status/viewer") == ("viewer",)
    assert SPEAKERS["detector/score"] == ("detector",) and SPEAKERS["detector/score/query"] == ("tracker",)
    assert speakers("frame/secret") == ()


def test_the_readme_prints_the_graph():
    readme = (ROOT / "README.md").read_text()
    block = readme.split("<!-- polartrack graph -->\n")[1].split("\n<!-- /polartrack graph -->")[0]
    assert block == table(), "README's pipeline table is stale: paste `uv run polartrack graph`"
