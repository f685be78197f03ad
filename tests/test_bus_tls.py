"""Zenoh's TLS transport and access control as BusConfig sets them, on loopback, with
certificates made by tools/gen_certs.sh: a client without a certificate (or with one from
another CA) cannot connect, and a client that access control denies a key cannot publish on it
while an allowed one can (the negative control)."""

import shutil
import subprocess
import time
from pathlib import Path

import pytest

from services.bus import BusUnavailable, BusConfig, TlsConfig, open_session
from services.launcher import free_ports

REPO = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed"),
              pytest.mark.slow]  # routers and clients on a loopback bus


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    d = tmp_path_factory.mktemp("certs")
    for name, clients in (("ok", ["ingest", "viewer", "intruder"]), ("other", ["ingest"])):
        subprocess.run(["bash", str(REPO / "tools/gen_certs.sh"), str(d / name), *sum((["--client", c] for c in clients), [])],
                       check=True, capture_output=True, timeout=60)
    return d


def tls(d, who=None, ca=None):
    return TlsConfig(root_ca_certificate=str((ca or d) / "ca.pem"),
                     certificate=str(d / f"{who}.pem") if who else None, private_key=str(d / f"{who}.key") if who else None)


DENY_INTRUDER = {"enabled": True, "default_permission": "allow",
                 "rules": [{"id": "no-put", "messages": ["put"], "flows": ["ingress"], "permission": "deny",
                            "key_exprs": ["polartrack/**"]}],
                 "subjects": [{"id": "intruders", "cert_common_names": ["intruder"]}],
                 "policies": [{"rules": ["no-put"], "subjects": ["intruders"]}]}


@pytest.fixture()
def router(certs):
    d = certs / "ok"
    port = free_ports(1)[0]
    bus = BusConfig(stream="tls", mode="router", listen=[f"tls/localhost:{port}"], tls=tls(d, "router"),
                    access_control=DENY_INTRUDER)
    with open_session(bus):
        yield port, d


def client(port, t):
    return open_session(BusConfig(stream="tls", mode="client", connect=[f"tls/localhost:{port}"], tls=t))


def test_a_client_without_the_certificate_cannot_connect(router, certs):
    port, d = router
    with pytest.raises(BusUnavailable, match="cannot join the Zenoh bus"):
        client(port, tls(d))  # no client certificate (mTLS)
    with pytest.raises(BusUnavailable, match="cannot join the Zenoh bus"):
        client(port, tls(certs / "other", "ingest", ca=d))  # a certificate from another CA
    with pytest.raises(BusUnavailable, match="cannot join the Zenoh bus"):  # no TLS at all: nothing listens on plain TCP
        open_session(BusConfig(stream="tls", mode="client", connect=[f"tcp/127.0.0.1:{port}"]))
    with client(port, tls(d, "ingest")):  # the control: the deployment's certificate connects
        pass


def test_access_control_denies_a_key_to_a_denied_client(router):
    port, d = router
    got = []
    with client(port, tls(d, "viewer")) as viewer, client(port, tls(d, "ingest")) as ingest, \
            client(port, tls(d, "intruder")) as intruder:
        viewer.declare_subscriber("polartrack/tls/**", lambda s: got.append(s.payload.to_bytes()))
        time.sleep(0.5)
        for i in range(5):
            intruder.put("polartrack/tls/frame/info", b"forged %d" % i)
            ingest.put("polartrack/tls/frame/info", b"genuine %d" % i)
        deadline = time.monotonic() + 5
        while len(got) < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)
    assert got == [b"genuine %d" % i for i in range(5)]
