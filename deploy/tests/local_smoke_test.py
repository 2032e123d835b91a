#!/usr/bin/python3
"""Starts surfacer-server exactly as deploy/ describes it, without Docker or Kubernetes, and checks it works.

Usage: local_smoke_test.py DEPLOY_DIR SERVER_BIN CLI_BIN

1. docker-compose.yml: the first replica's entrypoint and command, run through /bin/sh with its HOSTNAME, its
   named volume and file secrets mapped to temporary directories (secrets from make-dev-secrets.sh). The compose
   healthcheck command must report SERVING over TLS; the replica's store must land in <volume>/<hostname>; a job
   with the token must succeed, a call without it must be refused; the metrics port must serve surfacer_* metrics;
   after SIGTERM and a restart the job is still listed (the store is durable).
2. k8s/deployment.yaml: the server container's args with its volumes mapped (Secrets filled with the same
   throw-away secrets). What the kubelet's readiness/liveness probes dial (plain-text gRPC on the probe port) must
   answer SERVING, and the TLS port too.
Ports are replaced by free loopback ports. Exit 77 (CTest: skipped) without openssl, which makes the certificates.
"""
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import yaml

failures: list[str] = []


def expect(condition: bool, message: str) -> bool:
    if not condition:
        failures.append(message)
        print(f"FAIL: {message}", flush=True)
    return condition


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def replace_ports(text: str, ports: dict[int, int]) -> str:
    return re.sub(r":(\d+)\b", lambda m: f":{ports.get(int(m.group(1)), int(m.group(1)))}", text)


def wait_serving(command: list[str], env: dict, seconds: float, server: subprocess.Popen) -> subprocess.CompletedProcess:
    """Runs a health command until it succeeds, the time is up, or the server has exited."""
    deadline = time.monotonic() + seconds
    while True:
        result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=30)
        if result.returncode == 0 or time.monotonic() > deadline or server.poll() is not None:
            return result
        time.sleep(0.2)


def path_mapper(mapping: dict[str, str], ports: dict[int, int]):
    """Rewrites container paths (at a path boundary, each once) to host paths, and container ports to free ones."""
    if not mapping:
        return lambda text: replace_ports(text, ports)
    pattern = re.compile("(?<![\\w/.-])(" + "|".join(re.escape(p) for p in sorted(mapping, key=len, reverse=True))
                         + ")(?=/|$|[^\\w.-])")
    return lambda text: replace_ports(pattern.sub(lambda m: mapping[m.group(1)], text), ports)


def stop(proc: subprocess.Popen, grace: float) -> int | None:
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return None


def compose_replica(deploy: Path, secrets: Path, tmp: Path, env: dict, cli: str, examples: Path) -> None:
    compose = yaml.safe_load((deploy / "docker-compose.yml").read_text())
    name, svc = next(iter(compose["services"].items()))
    volume_dir = tmp / "compose-volume"
    volume_dir.mkdir()
    mapping = {}  # container path -> host path, longest first
    for v in svc.get("volumes") or []:
        source, target = str(v).split(":")[:2]
        if source in (compose.get("volumes") or {}):
            mapping[target] = str(volume_dir)
    for s in svc.get("secrets") or []:
        secret = s if isinstance(s, str) else s["source"]
        mapping[f"/run/secrets/{secret}"] = str(secrets / Path(compose["secrets"][secret]["file"]).name)
    ports = {}
    for p in svc.get("ports") or []:
        ports[int(str(p).split(":")[-1])] = free_port()

    host = path_mapper(mapping, ports)
    entry = [host(str(x).replace("$$", "$")) for x in svc["entrypoint"]]
    command = [host(str(x)) for x in svc.get("command") or []]
    replica_env = dict(env, HOSTNAME=svc["hostname"])
    health = [host(str(x)) for x in svc["healthcheck"]["test"]][1:]  # drop "CMD"
    health[0] = cli
    grace = float(str(svc.get("stop_grace_period", "10s")).rstrip("s"))
    print(f"compose {name}: {shlex.join(entry + command)}", flush=True)

    log = open(tmp / "compose-server.log", "w")
    proc = subprocess.Popen(entry + command, env=replica_env, stdout=log, stderr=subprocess.STDOUT)
    try:
        result = wait_serving(health, env, 20, proc)
        expect(result.returncode == 0 and "SERVING" in result.stdout,
               f"compose healthcheck {shlex.join(health)}: exit {result.returncode} {result.stdout}{result.stderr}")
        store = volume_dir / svc["hostname"]
        expect(store.is_dir() and any(store.iterdir()),
               f"the replica's store is not in its own subdirectory {store} of the shared volume")
        server = next(a for a in health if re.match(r"localhost:\d+$", a))
        tls = ["--tls-ca", mapping["/run/secrets/surfacer_ca"]]
        token = ["--token-file", str(secrets / "client-token")]
        out = tmp / "compose-out"
        run = subprocess.run([cli, "--server", server, *tls, *token, "run", "isosurface", "--scene",
                              str(examples / "sphere.json"), "--cells", "16", "-o", str(out)],
                             env=env, capture_output=True, text=True, timeout=60)
        expect(run.returncode == 0 and (out / "frame_0000.glb").is_file(),
               f"a job with the token: exit {run.returncode}\n{run.stderr}")
        job = re.search(r"\b(j-[0-9a-f]+)", run.stdout + run.stderr)
        anonymous = subprocess.run([cli, "--server", server, *tls, "list"], env=env, capture_output=True, text=True,
                                   timeout=30)
        expect(anonymous.returncode != 0 and "UNAUTHENTICATED" in anonymous.stderr,
               f"a call without a token: exit {anonymous.returncode} {anonymous.stderr}")
        metrics = next((a for a in command if a.startswith("--metrics-listen")), None)
        if expect(metrics is not None, "the replica has no --metrics-listen"):
            url = f"http://127.0.0.1:{metrics.rsplit(':', 1)[1]}/metrics"
            try:
                with urllib.request.urlopen(url, timeout=5) as response:
                    body = response.read().decode()
                expect(response.status == 200 and re.search(r"^surfacer_\w+", body, re.M) is not None,
                       f"{url}: status {response.status}, no surfacer_* metric in {body[:200]!r}")
            except OSError as e:
                expect(False, f"{url} (the published metrics port): {e}")
        code = stop(proc, grace)
        expect(code == 0, f"SIGTERM: the replica exited {code} within stop_grace_period {grace:g} s")

        proc = subprocess.Popen(entry + command, env=replica_env, stdout=log, stderr=subprocess.STDOUT)
        wait_serving(health, env, 20, proc)
        listed = subprocess.run([cli, "--server", server, *tls, *token, "list"], env=env, capture_output=True,
                                text=True, timeout=30)
        expect(job is not None and job.group(1) in listed.stdout,
               f"after a restart the replica no longer lists job {job and job.group(1)}: {listed.stdout}"
               f"{listed.stderr}")
    finally:
        if proc.poll() is None:
            stop(proc, grace)
        log.close()
    if not failures:
        print(f"compose {name}: healthcheck SERVING over TLS, store in {svc['hostname']}/, token enforced, "
              "job kept across a restart", flush=True)


def k8s_server(deploy: Path, secrets: Path, tmp: Path, env: dict, server_bin: str, cli: str) -> None:
    docs = [d for d in yaml.safe_load_all((deploy / "k8s" / "deployment.yaml").read_text()) if d]
    deployment = next(d for d in docs if d["kind"] == "Deployment")
    pod = deployment["spec"]["template"]["spec"]
    container = next(c for c in pod["containers"] if any(str(a).startswith("--listen") for a in c["args"]))
    volumes = {v["name"]: v for v in pod.get("volumes") or []}
    mapping = {}
    for m in container.get("volumeMounts") or []:
        target = tmp / "k8s" / m["name"]
        target.mkdir(parents=True)
        secret = (volumes[m["name"]].get("secret") or {}).get("secretName")
        if secret == "surfacer-tls":
            shutil.copy(secrets / "tls.crt", target / "tls.crt")
            shutil.copy(secrets / "tls.key", target / "tls.key")
            shutil.copy(secrets / "ca.crt", target / "ca.crt")
        elif secret == "surfacer-tokens":
            shutil.copy(secrets / "tokens", target / "tokens")
        mapping[m["mountPath"]] = str(target)
    ports = {p["containerPort"]: free_port() for p in container.get("ports") or []}

    host = path_mapper(mapping, ports)
    args = [host(str(a)) for a in container["args"]]
    print(f"k8s container {container['name']}: {shlex.join([server_bin] + args)}", flush=True)
    log = open(tmp / "k8s-server.log", "w")
    proc = subprocess.Popen([server_bin] + args, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        time.sleep(0.3)
        if not expect(proc.poll() is None, f"the server exited {proc.returncode} at start"):
            return
        for kind in ("startupProbe", "readinessProbe", "livenessProbe"):
            probe = container.get(kind)
            if not probe:
                continue
            port = ports[probe["grpc"]["port"]]
            # What the kubelet does: grpc.health.v1 Check over plain text, on the pod's address and the probe port.
            patience = 15 if kind == "startupProbe" else 0  # once started, every probe must pass at once
            result = wait_serving([cli, "--server", f"127.0.0.1:{port}", "--timeout", "2", "health"], env, patience,
                                  proc)
            expect(result.returncode == 0 and "SERVING" in result.stdout,
                   f"{kind} (plain-text gRPC health on port {probe['grpc']['port']}): exit {result.returncode} "
                   f"{result.stdout}{result.stderr}")
        listen = next(a for a in args if a.startswith("--listen"))
        port = listen.rsplit(":", 1)[1]
        result = wait_serving([cli, "--server", f"localhost:{port}", "--tls-ca", str(secrets / "ca.crt"),
                               "--tls-server-name", "surfacer-headless.surfacer.svc.cluster.local", "health"], env, 5, proc)
        expect(result.returncode == 0, f"the TLS port with the headless Service's name: exit {result.returncode} "
                                       f"{result.stderr}")
        grace = pod.get("terminationGracePeriodSeconds", 30)
        code = stop(proc, grace)
        expect(code == 0, f"SIGTERM: the server exited {code} within terminationGracePeriodSeconds {grace}")
    finally:
        if proc.poll() is None:
            stop(proc, 5)
        log.close()
    if not failures:
        print("k8s: probes answer SERVING on the plain-text probe port, TLS port answers for the headless name",
              flush=True)


def main() -> int:
    if len(sys.argv) != 4:
        print(__doc__, file=sys.stderr)
        return 2
    deploy = Path(sys.argv[1]).resolve()
    server_bin, cli = os.path.abspath(sys.argv[2]), os.path.abspath(sys.argv[3])
    if shutil.which("openssl") is None:
        print("skipped: openssl is not installed (it makes the throw-away certificates)")
        return 77
    env = dict(os.environ)
    env["PATH"] = f"{Path(server_bin).parent}:{Path(cli).parent}:{env.get('PATH', '/usr/bin:/bin')}"
    for var in ("SURFACER_SERVER", "SURFACER_TOKEN"):
        env.pop(var, None)
    with tempfile.TemporaryDirectory(prefix="surfacer-deploy-smoke-") as tmp:
        tmp = Path(tmp)
        secrets = tmp / "secrets"
        made = subprocess.run([str(deploy / "make-dev-secrets.sh"), "--dir", str(secrets)], capture_output=True,
                              text=True, timeout=60)
        if not expect(made.returncode == 0, f"make-dev-secrets.sh: {made.stderr}"):
            return 1
        for step in (lambda: compose_replica(deploy, secrets, tmp, env, cli, deploy.parent / "examples" / "scenes"),
                     lambda: k8s_server(deploy, secrets, tmp, env, server_bin, cli)):
            try:
                step()
            except (StopIteration, KeyError, subprocess.TimeoutExpired, OSError) as e:
                expect(False, f"{type(e).__name__}: {e}")
        if failures:
            for log in sorted(tmp.glob("*.log")):
                print(f"--- {log.name} (last lines)\n" + "\n".join(log.read_text().splitlines()[-15:]))
    if failures:
        print(f"{len(failures)} failure(s)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
