#!/usr/bin/python3
"""Checks the deployment files under deploy/ without a cluster or a container engine.

Usage: scripts/check_deploy.py [--self-test] DEPLOY_DIR [SERVER_BIN [CLI_BIN]]

Parses every YAML file under DEPLOY_DIR (Kubernetes manifests, the compose file) and deploy/Dockerfile, and checks
what a broken deployment would get wrong: the kinds (Deployment, StatefulSet, headless Service, HPA,
PodDisruptionBudget, Indexed Job, Kustomization); native gRPC liveness/readiness probes on a port that serves
plain-text health; container ports; one image name everywhere; resource requests; selectors that match the pod labels;
the HPA's target; the StatefulSet's serviceName, podManagementPolicy and volumeClaimTemplates (the --data-dir on one);
the Job's completion mode, JOB_COMPLETION_INDEX and JOB_COMPLETIONS; grace periods longer than the drain; files
passed to flags mounted from volumes; the Dockerfile's stages. Services, HPA, PDB and StatefulSet are checked against
the workloads of each kustomization they are built into (deploy/k8s: the Deployment; deploy/k8s/durable: the
StatefulSet, and the HPA after the overlay's patches), as `kubectl kustomize` would render them (resources and
strategic-merge patches). With SERVER_BIN (and CLI_BIN), every server flag in the manifests (and every CLI flag) must
be one that `--help` lists.

--self-test then breaks the manifests in memory, one way at a time (a dropped probe, a broken selector, ...), and
fails unless each break is reported. Exit status: 0 all good, 1 a check or the self-test failed, 2 usage.
"""
from __future__ import annotations

import copy
import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

try:
    import yaml
except ImportError:  # pragma: no cover
    print("check_deploy: needs PyYAML (Debian: apt-get install python3-yaml; run with /usr/bin/python3)",
          file=sys.stderr)
    sys.exit(2)

IMAGE_REPO = "surfacer"
ENTRY_SCRIPT = "indexed-job-entry.sh"
LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "[::1]", "::1"}


@dataclass
class Doc:
    path: str  # relative to the deploy directory
    index: int  # position in a multi-document file
    body: dict

    @property
    def where(self) -> str:
        kind = self.body.get("kind", "?")
        name = (self.body.get("metadata") or {}).get("name", "?")
        return f"{self.path}: {kind} {name}"


@dataclass
class Model:
    docs: list[Doc] = field(default_factory=list)  # Kubernetes objects (kustomization included)
    compose: dict | None = None
    compose_path: str = ""
    dockerfile: str | None = None
    entry_script: str | None = None
    cmake: str | None = None  # the repository's top CMakeLists.txt
    yaml_files: list[str] = field(default_factory=list)  # every YAML file, relative to the deploy directory


@dataclass
class Flags:
    server: set[str] | None = None
    cli_global: set[str] | None = None
    cli_sub: dict[str, set[str]] = field(default_factory=dict)  # "health", "run particles" -> flags


# ---------------------------------------------------------------------------------------------------------- loading
def load(deploy: Path) -> tuple[Model, list[str]]:
    model, errors = Model(), []
    for path in sorted(deploy.rglob("*")):
        if path.suffix not in (".yaml", ".yml") or not path.is_file():
            continue
        rel = str(path.relative_to(deploy))
        try:
            bodies = [b for b in yaml.safe_load_all(path.read_text()) if b is not None]
        except yaml.YAMLError as e:
            errors.append(f"{rel}: not valid YAML: {e}")
            continue
        model.yaml_files.append(rel)
        for i, body in enumerate(bodies):
            if not isinstance(body, dict):
                errors.append(f"{rel}: document {i} is a {type(body).__name__}, not a mapping")
            elif "services" in body and "kind" not in body:
                model.compose, model.compose_path = body, rel
            elif "kind" not in body or "apiVersion" not in body:
                errors.append(f"{rel}: document {i} has no kind/apiVersion (neither a Kubernetes object nor a "
                              "compose file with services:)")
            else:
                model.docs.append(Doc(rel, i, body))
    dockerfile = deploy / "Dockerfile"
    model.dockerfile = dockerfile.read_text() if dockerfile.is_file() else None
    entry = deploy / ENTRY_SCRIPT
    model.entry_script = entry.read_text() if entry.is_file() else None
    cmake = deploy.parent / "CMakeLists.txt"
    model.cmake = cmake.read_text() if cmake.is_file() else None
    return model, errors


def help_flags(command: list[str]) -> set[str]:
    """Option names (--long and -s) that a CLI11 --help lists, from the option column only."""
    result = subprocess.run(command + ["--help"], capture_output=True, text=True, timeout=30)
    if result.returncode != 0:
        raise RuntimeError(f"`{' '.join(command)} --help` exited {result.returncode}: {result.stderr.strip()}")
    names = set()
    for line in result.stdout.splitlines():
        m = re.match(r"^ {2}(-[^\s]+)", line)
        if m:
            for name in m.group(1).split(","):
                names.add(name.split("=")[0])
    if not names:
        raise RuntimeError(f"`{' '.join(command)} --help` lists no options")
    return names


def load_flags(server_bin: str | None, cli_bin: str | None) -> Flags:
    flags = Flags()
    if server_bin:
        flags.server = help_flags([server_bin])
    if cli_bin:
        flags.cli_global = help_flags([cli_bin])
        for sub in ("health", "run particles"):
            flags.cli_sub[sub] = help_flags([cli_bin] + sub.split())
    return flags


# ---------------------------------------------------------------------------------------------------------- helpers
def parse_args(args: list) -> dict[str, str | None]:
    """--flag=value / --flag value / --switch -> {flag: value or None}."""
    out: dict[str, str | None] = {}
    args = [str(a) for a in args]
    i = 0
    while i < len(args):
        a = args[i]
        if a.startswith("-"):
            if "=" in a:
                name, value = a.split("=", 1)
                out[name] = value
            elif i + 1 < len(args) and not args[i + 1].startswith("-"):
                out[a] = args[i + 1]
                i += 1
            else:
                out[a] = None
        i += 1
    return out


def host_port(value: str | None) -> tuple[str, int] | None:
    if not value or ":" not in value:
        return None
    host, _, port = value.rpartition(":")
    return (host, int(port)) if port.isdigit() else None


def quantity_bytes(q) -> float | None:
    if q is None:
        return None
    m = re.fullmatch(r"([0-9.]+)\s*(Ki|Mi|Gi|Ti|Pi|K|M|G|T|P|k)?", str(q))
    if not m:
        return None
    scale = {None: 1, "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40, "Pi": 2**50,
             "k": 1e3, "K": 1e3, "M": 1e6, "G": 1e9, "T": 1e12, "P": 1e15}[m.group(2)]
    return float(m.group(1)) * scale


def seconds(value) -> float | None:
    """'90s', '1m30s', 90 -> seconds."""
    if value is None:
        return None
    if isinstance(value, (int, float)):
        return float(value)
    total, matched = 0.0, False
    for number, unit in re.findall(r"([0-9.]+)(h|ms|m|s|us)", str(value)):
        total += float(number) * {"h": 3600, "m": 60, "s": 1, "ms": 1e-3, "us": 1e-6}[unit]
        matched = True
    return total if matched else None


def selects(selector: dict | None, labels: dict | None) -> bool:
    return bool(selector) and all((labels or {}).get(k) == v for k, v in selector.items())


def image_repo(image: str) -> tuple[str, str]:
    name, _, tag = image.rpartition(":") if ":" in image.split("/")[-1] else (image, "", "")
    return name, tag


def project_version(cmake: str | None) -> str | None:
    m = re.search(r"project\(\s*surfacer\s+VERSION\s+([0-9.]+)", cmake or "")
    return m.group(1) if m else None


def pod_spec(doc: Doc) -> dict:
    return (((doc.body.get("spec") or {}).get("template") or {}).get("spec")) or {}


def pod_labels(doc: Doc) -> dict:
    return ((((doc.body.get("spec") or {}).get("template") or {}).get("metadata")) or {}).get("labels") or {}


def pod_volumes(doc: Doc) -> dict:
    """Volumes by name, a StatefulSet's volumeClaimTemplates included (as {"volumeClaimTemplate": template})."""
    volumes = {v.get("name"): v for v in pod_spec(doc).get("volumes") or []}
    if doc.body.get("kind") == "StatefulSet":
        for t in (doc.body.get("spec") or {}).get("volumeClaimTemplates") or []:
            name = (t.get("metadata") or {}).get("name")
            volumes.setdefault(name, {"name": name, "volumeClaimTemplate": t})
    return volumes


def merge_patch(target: dict, patch: dict) -> None:
    """Strategic merge as far as these manifests need it: maps merge, lists and scalars replace."""
    for k, v in patch.items():
        if isinstance(v, dict) and isinstance(target.get(k), dict):
            merge_patch(target[k], v)
        else:
            target[k] = copy.deepcopy(v)


WORKLOAD_KINDS = ("Deployment", "StatefulSet")


def mounted(path: str, container: dict, volumes: dict) -> tuple[dict, dict] | None:
    """The (volumeMount, volume) that holds path, the deepest mount first."""
    best = None
    for m in container.get("volumeMounts") or []:
        mp = m.get("mountPath", "").rstrip("/")
        if (path == mp or path.startswith(mp + "/")) and (best is None or len(mp) > len(best[0]["mountPath"])):
            best = (m, volumes.get(m.get("name"), {}))
    return best


# ----------------------------------------------------------------------------------------------------------- checks
class Checker:
    def __init__(self, model: Model, flags: Flags):
        self.m, self.flags, self.errors = model, flags, []

    def err(self, where: str, message: str) -> None:
        self.errors.append(f"{where}: {message}")

    def of_kind(self, kind: str) -> list[Doc]:
        return [d for d in self.m.docs if d.body.get("kind") == kind]

    def run(self) -> list[str]:
        for kind in ("Deployment", "StatefulSet", "Service", "HorizontalPodAutoscaler", "PodDisruptionBudget", "Job",
                     "Kustomization"):
            if not self.of_kind(kind):
                self.errors.append(f"deploy/: no {kind} manifest")
        for d in self.m.docs:
            if d.body.get("kind") != "Kustomization" and not (d.body.get("metadata") or {}).get("name"):
                self.err(d.where, "metadata.name is missing")
        for d in self.m.docs:
            if d.body.get("kind") in WORKLOAD_KINDS:
                self.deployment(d)
        self.kustomization()
        for kdir, objects in self.renders().items():
            workloads = [d for d in objects if d.body.get("kind") in WORKLOAD_KINDS]
            if not workloads:
                self.err(f"{kdir}/kustomization.yaml", "builds no Deployment or StatefulSet")
                continue
            self.services(kdir, objects, workloads)
            self.hpa(objects, workloads)
            self.pdb(objects, workloads)
            for d in workloads:
                if d.body.get("kind") == "StatefulSet":
                    self.statefulset_service(d, objects)
        for j in self.of_kind("Job"):
            self.job(j)
        self.images()
        self.compose()
        self.dockerfile()
        return self.errors

    # -- server flags shared by every place that starts surfacer-server
    def server_flags(self, where: str, args: dict[str, str | None]) -> None:
        if self.flags.server is None:
            return
        unknown = [name for name in args if name not in self.flags.server]
        if unknown:
            self.err(where, f"not surfacer-server flags (per its --help): {', '.join(unknown)}")

    def cli_flags(self, where: str, args: list[str], sub: str) -> None:
        if self.flags.cli_global is None:
            return
        known = self.flags.cli_global | self.flags.cli_sub.get(sub, set())
        unknown = [a.split("=")[0] for a in args if a.startswith("-") and a.split("=")[0] not in known]
        if unknown:
            self.err(where, f"not flags of `surfacer {sub}` (per surfacer --help and surfacer {sub} --help): "
                            f"{', '.join(unknown)}")

    def listen_rules(self, where: str, args: dict) -> None:
        listen = host_port(args.get("--listen"))
        if listen is None:
            self.err(where, "surfacer-server needs --listen HOST:PORT (its default is loopback only)")
            return
        tls = "--tls-cert" in args or "--tls-key" in args
        if tls and not ("--tls-cert" in args and "--tls-key" in args):
            self.err(where, "--tls-cert and --tls-key go together")
        if not tls and listen[0] not in LOOPBACK_HOSTS and "--allow-insecure" not in args:
            self.err(where, f"plain text on {args['--listen']} is refused by the server: give --tls-cert/--tls-key "
                            "(or --allow-insecure behind a proxy or mesh that provides TLS)")
        if "--tokens-file" not in args:
            self.err(where, "no --tokens-file: every caller could see and cancel every job")
        if "--data-dir" not in args and "--memory-only" not in args:
            self.err(where, "no --data-dir: the job store would land in the working directory")

    def deployment(self, d: Doc) -> None:
        spec, pod = d.body.get("spec") or {}, pod_spec(d)
        if d.body.get("apiVersion") != "apps/v1":
            self.err(d.where, f"apiVersion {d.body.get('apiVersion')}, expected apps/v1")
        if not selects((spec.get("selector") or {}).get("matchLabels"), pod_labels(d)):
            self.err(d.where, "spec.selector.matchLabels do not match the pod template's labels")
        containers = pod.get("containers") or []
        server = next((c for c in containers if "--listen" in parse_args(c.get("args") or [])), None)
        if server is None:
            self.err(d.where, "no container runs surfacer-server with --listen in its args")
            return
        where = f"{d.where} container {server.get('name')}"
        args = parse_args(server.get("args") or [])
        self.server_flags(where, args)
        self.listen_rules(where, args)
        ports = {p.get("containerPort"): p for p in server.get("ports") or []}
        named = {p.get("name"): p.get("containerPort") for p in server.get("ports") or []}
        listen, metrics = host_port(args.get("--listen")), host_port(args.get("--metrics-listen"))
        health = host_port(args.get("--health-listen"))
        for flag, hp in (("--listen", listen), ("--metrics-listen", metrics), ("--health-listen", health)):
            if hp and hp[1] not in ports:
                self.err(where, f"{flag} port {hp[1]} is not among the container ports {sorted(ports)}")
        if metrics is None:
            self.err(where, "no --metrics-listen: Prometheus has nothing to scrape")
        else:
            ann = (((spec.get("template") or {}).get("metadata")) or {}).get("annotations") or {}
            if str(ann.get("prometheus.io/scrape")) != "true" or str(ann.get("prometheus.io/port")) != str(metrics[1]):
                self.err(d.where, f"pod annotations need prometheus.io/scrape: \"true\" and prometheus.io/port: "
                                  f"\"{metrics[1]}\" (the --metrics-listen port)")
        tls = "--tls-cert" in args
        for kind in ("readinessProbe", "livenessProbe"):
            probe = server.get(kind)
            if not probe:
                self.err(where, f"no {kind}")
                continue
            grpc = probe.get("grpc")
            if not isinstance(grpc, dict):
                self.err(where, f"{kind} is not a native gRPC probe (grpc: {{port: N}})")
                continue
            port = grpc.get("port")
            if not isinstance(port, int):
                self.err(where, f"{kind}.grpc.port must be a number (gRPC probes take no named ports), got {port!r}")
                continue
            if port not in ports:
                self.err(where, f"{kind}.grpc.port {port} is not a container port")
            if tls and listen and port == listen[1]:
                self.err(where, f"{kind} probes the TLS port {port}: Kubernetes' native gRPC probes cannot speak "
                                "TLS; probe the plain-text --health-listen port")
            elif health and port not in (health[1],) and not (listen and port == listen[1] and not tls):
                self.err(where, f"{kind}.grpc.port {port} serves no gRPC health (--listen, --health-listen)")
            elif not health and not (listen and port == listen[1]):
                self.err(where, f"{kind}.grpc.port {port} serves no gRPC health (--listen, --health-listen)")
        drain = float(args.get("--drain-seconds") or 30)
        grace = pod.get("terminationGracePeriodSeconds", 30)
        if not grace > drain:
            self.err(d.where, f"terminationGracePeriodSeconds ({grace}) must exceed --drain-seconds ({drain:g}), "
                              "or running jobs are killed before they finish draining")
        live = server.get("livenessProbe") or {}
        tolerated = live.get("failureThreshold", 3) * live.get("periodSeconds", 10)
        if live and not tolerated > drain:
            self.err(where, f"livenessProbe tolerates {tolerated} s of NOT_SERVING (failureThreshold x "
                            f"periodSeconds), less than --drain-seconds ({drain:g}): a draining pod would be killed")
        res = server.get("resources") or {}
        for r in ("cpu", "memory"):
            if r not in (res.get("requests") or {}):
                self.err(where, f"resources.requests.{r} is missing (the scheduler and the CPU HPA need it)")
        if "memory" not in (res.get("limits") or {}):
            self.err(where, "resources.limits.memory is missing")
        self.security(where, pod, server)
        volumes = pod_volumes(d)
        for flag in ("--tls-cert", "--tls-key", "--tls-client-ca", "--tokens-file", "--data-dir"):
            if args.get(flag):
                self.file_flag(where, flag, args[flag], server, volumes, writable=(flag == "--data-dir"))
        data = mounted(args.get("--data-dir") or "", server, volumes)
        limit = quantity_bytes(((data or ({}, {}))[1].get("emptyDir") or {}).get("sizeLimit"))
        retain = args.get("--retain-bytes")
        if limit and retain and retain.isdigit() and int(retain) >= limit:
            self.err(where, f"--retain-bytes ({retain}) must stay below the data volume's sizeLimit ({limit:.0f} "
                            "bytes), or the kubelet evicts the pod before retention runs")
        if named.get("grpc") is None:
            self.err(where, "no container port named grpc (the Services' targetPort)")
        if d.body.get("kind") == "StatefulSet":
            self.statefulset(d, where, args, data)

    def statefulset(self, d: Doc, where: str, args: dict, data: tuple[dict, dict] | None) -> None:
        spec = d.body.get("spec") or {}
        if spec.get("podManagementPolicy") != "Parallel":
            self.err(d.where, f"podManagementPolicy is {spec.get('podManagementPolicy', 'OrderedReady')!r}, expected "
                              "Parallel: with OrderedReady, a scale-up waits for each pod's store restore in turn and "
                              "one pod that never turns ready blocks every higher ordinal")
        templates = spec.get("volumeClaimTemplates") or []
        if not templates:
            self.err(d.where, "no volumeClaimTemplates: the pods' job stores would not survive their deletion "
                              "(use the Deployment of deploy/k8s for that)")
        plain = {v.get("name") for v in pod_spec(d).get("volumes") or []}
        for t in templates:
            name = (t.get("metadata") or {}).get("name")
            tspec = t.get("spec") or {}
            if name in plain:
                self.err(d.where, f"volume {name} is both a pod volume and a volumeClaimTemplate")
            if not quantity_bytes(((tspec.get("resources") or {}).get("requests") or {}).get("storage")):
                self.err(d.where, f"volumeClaimTemplate {name}: resources.requests.storage is missing")
            modes = tspec.get("accessModes") or []
            if not modes or not set(modes) <= {"ReadWriteOnce", "ReadWriteOncePod"}:
                self.err(d.where, f"volumeClaimTemplate {name}: accessModes {modes}, expected [ReadWriteOnce] (one "
                                  "pod per store; SQLite must not be shared)")
        if "--data-dir" not in args:
            return
        if data is None or "volumeClaimTemplate" not in data[1]:
            on = f"on volume {data[0].get('name')}" if data else "on no volume"
            self.err(where, f"--data-dir {args['--data-dir']} is not on a volumeClaimTemplate (it is {on}): the store "
                            "would not come back with the pod")
            return
        size = quantity_bytes(((data[1]["volumeClaimTemplate"].get("spec") or {}).get("resources") or {})
                              .get("requests", {}).get("storage"))
        retain = args.get("--retain-bytes")
        if size and retain and retain.isdigit() and int(retain) >= size:
            self.err(where, f"--retain-bytes ({retain}) must stay below the data claim's storage request ({size:.0f} "
                            "bytes), or the volume fills up before retention runs")

    def statefulset_service(self, d: Doc, objects: list[Doc]) -> None:
        name = (d.body.get("spec") or {}).get("serviceName")
        headless = [s for s in objects if s.body.get("kind") == "Service"
                    and (s.body.get("spec") or {}).get("clusterIP") == "None"
                    and selects((s.body.get("spec") or {}).get("selector"), pod_labels(d))]
        names = sorted((s.body.get("metadata") or {}).get("name") for s in headless)
        if name not in names:
            self.err(d.where, f"serviceName {name!r} is not a headless Service selecting its pods ({names}): the pods "
                              "get no stable DNS names")

    def security(self, where: str, pod: dict, container: dict) -> None:
        psc, csc = pod.get("securityContext") or {}, container.get("securityContext") or {}
        if not (csc.get("runAsNonRoot") or psc.get("runAsNonRoot")):
            self.err(where, "securityContext.runAsNonRoot is not true")
        uid = csc.get("runAsUser", psc.get("runAsUser"))
        if uid == 0:
            self.err(where, "runs as uid 0")
        if csc.get("readOnlyRootFilesystem") is not True:
            self.err(where, "securityContext.readOnlyRootFilesystem is not true")
        if csc.get("allowPrivilegeEscalation") is not False:
            self.err(where, "securityContext.allowPrivilegeEscalation is not false")

    def file_flag(self, where, flag, path, container, volumes, writable) -> None:
        hit = mounted(path, container, volumes)
        if hit is None:
            self.err(where, f"{flag} {path} is on no volume (the root file system is read-only / not in the image)")
            return
        mount, volume = hit
        if writable and (mount.get("readOnly") or "secret" in volume or "configMap" in volume):
            self.err(where, f"{flag} {path} must be writable, but volume {mount.get('name')} is read-only")
        secret = (volume.get("secret") or {}).get("secretName")
        if secret:
            key = path[len(mount["mountPath"].rstrip("/")) + 1:]
            defined = [d for d in self.of_kind("Secret") if (d.body.get("metadata") or {}).get("name") == secret]
            for d in defined:
                keys = set((d.body.get("stringData") or {}) | (d.body.get("data") or {}))
                if key not in keys:
                    self.err(where, f"{flag} {path}: Secret {secret} ({d.path}) has no key {key} (keys: "
                                    f"{sorted(keys)})")
            if not defined:
                self.err(where, f"{flag} {path}: Secret {secret} is described in no YAML file under deploy/ "
                                "(keep a template such as k8s/secrets.example.yaml)")

    def services(self, kdir: str, objects: list[Doc], workloads: list[Doc]) -> None:
        job_labels = [pod_labels(j) for j in self.of_kind("Job")]
        headless = 0
        kinds = "/".join(sorted({d.body.get("kind") for d in workloads}))
        services = [s for s in objects if s.body.get("kind") == "Service"]
        for s in services:
            spec = s.body.get("spec") or {}
            selector = spec.get("selector")
            targets = [d for d in workloads if selects(selector, pod_labels(d))]
            if not targets:
                self.err(s.where, f"selector {selector} matches no {kinds}'s pod labels")
                continue
            if any(selects(selector, labels) for labels in job_labels):
                self.err(s.where, f"selector {selector} also matches the Job's pods: clients would reach them")
            named = {}
            for d in targets:
                for c in pod_spec(d).get("containers") or []:
                    for p in c.get("ports") or []:
                        named[p.get("name")] = p.get("containerPort")
            for p in spec.get("ports") or []:
                target = p.get("targetPort", p.get("port"))
                if target not in named and target not in named.values():
                    self.err(s.where, f"port {p.get('name')} targets {target!r}, which no selected container exposes "
                                      f"({sorted(str(k) for k in named)})")
            if spec.get("clusterIP") == "None":
                headless += 1
                if spec.get("publishNotReadyAddresses"):
                    self.err(s.where, "publishNotReadyAddresses: true would hand draining pods to clients")
                if not any(p.get("targetPort") == "grpc" or p.get("port") == 50051 for p in spec.get("ports") or []):
                    self.err(s.where, "the headless Service has no gRPC port")
        if services and not headless:
            self.errors.append(f"{kdir}/kustomization.yaml: builds no headless Service (clusterIP: None) for "
                               "client-side round-robin")

    def hpa(self, objects: list[Doc], workloads: list[Doc]) -> None:
        names = {(d.body.get("kind"), (d.body.get("metadata") or {}).get("name")) for d in workloads}
        for h in (o for o in objects if o.body.get("kind") == "HorizontalPodAutoscaler"):
            spec = h.body.get("spec") or {}
            if h.body.get("apiVersion") != "autoscaling/v2":
                self.err(h.where, f"apiVersion {h.body.get('apiVersion')}, expected autoscaling/v2")
            ref = spec.get("scaleTargetRef") or {}
            if (ref.get("kind"), ref.get("name")) not in names or ref.get("apiVersion") != "apps/v1":
                self.err(h.where, f"scaleTargetRef {ref.get('apiVersion')} {ref.get('kind')}/{ref.get('name')} names "
                                  "no workload built with it "
                                  f"({', '.join(f'apps/v1 {k}/{n}' for k, n in sorted(names))})")
            if not any((m.get("resource") or {}).get("name") == "cpu" for m in spec.get("metrics") or []):
                self.err(h.where, "no CPU resource metric")
            lo, hi = spec.get("minReplicas", 1), spec.get("maxReplicas")
            if not isinstance(hi, int) or lo > hi:
                self.err(h.where, f"minReplicas {lo} / maxReplicas {hi} are not a range")

    def pdb(self, objects: list[Doc], workloads: list[Doc]) -> None:
        hpa_min = min([(h.body.get("spec") or {}).get("minReplicas", 1)
                       for h in objects if h.body.get("kind") == "HorizontalPodAutoscaler"] or [1])
        for p in (o for o in objects if o.body.get("kind") == "PodDisruptionBudget"):
            spec = p.body.get("spec") or {}
            if p.body.get("apiVersion") != "policy/v1":
                self.err(p.where, f"apiVersion {p.body.get('apiVersion')}, expected policy/v1")
            selector = (spec.get("selector") or {}).get("matchLabels")
            if not any(selects(selector, pod_labels(d)) for d in workloads):
                self.err(p.where, f"selector {selector} matches no "
                                  f"{'/'.join(sorted({d.body.get('kind') for d in workloads}))}'s pod labels")
            if "minAvailable" not in spec and "maxUnavailable" not in spec:
                self.err(p.where, "needs minAvailable or maxUnavailable")
            if isinstance(spec.get("minAvailable"), int) and spec["minAvailable"] >= hpa_min:
                self.err(p.where, f"minAvailable {spec['minAvailable']} >= the HPA's minReplicas {hpa_min}: "
                                  "node drains would block")

    def job(self, j: Doc) -> None:
        spec, pod = j.body.get("spec") or {}, pod_spec(j)
        if j.body.get("apiVersion") != "batch/v1":
            self.err(j.where, f"apiVersion {j.body.get('apiVersion')}, expected batch/v1")
        if spec.get("completionMode") != "Indexed":
            self.err(j.where, f"completionMode is {spec.get('completionMode')!r}, expected Indexed (each pod takes "
                              "its frame range from JOB_COMPLETION_INDEX)")
        completions, parallelism = spec.get("completions"), spec.get("parallelism", 1)
        if not isinstance(completions, int) or completions < 1:
            self.err(j.where, f"completions {completions!r} must be a positive number")
            completions = None
        elif not isinstance(parallelism, int) or not 1 <= parallelism <= completions:
            self.err(j.where, f"parallelism {parallelism!r} must be in 1..completions ({completions})")
        if pod.get("restartPolicy") not in ("Never", "OnFailure"):
            self.err(j.where, "template.spec.restartPolicy must be Never or OnFailure")
        containers = pod.get("containers") or []
        if len(containers) != 1:
            self.err(j.where, f"{len(containers)} containers, expected 1")
            return
        c = containers[0]
        where = f"{j.where} container {c.get('name')}"
        command = [str(x) for x in (c.get("command") or []) + (c.get("args") or [])]
        if not any(Path(x).name in ("surfacer-indexed-job", ENTRY_SCRIPT) for x in command):
            self.err(where, f"does not run the entry script (surfacer-indexed-job = deploy/{ENTRY_SCRIPT})")
        if "JOB_COMPLETION_INDEX" not in (self.m.entry_script or ""):
            self.err(f"deploy/{ENTRY_SCRIPT}", "does not read JOB_COMPLETION_INDEX")
        env = {e.get("name"): e for e in c.get("env") or []}
        for name in ("FRAMES_TOTAL", "INPUT_PATTERN", "R_INNER", "OUT_DIR"):
            if name not in env:
                self.err(where, f"env {name} is missing (see deploy/{ENTRY_SCRIPT})")
        value = {k: str(e.get("value")) for k, e in env.items() if "value" in e}
        if "JOB_COMPLETIONS" in value and completions and value["JOB_COMPLETIONS"] != str(completions):
            self.err(where, f"env JOB_COMPLETIONS ({value['JOB_COMPLETIONS']}) differs from spec.completions "
                            f"({completions}): frame ranges would overlap or leave a gap")
        if "JOB_COMPLETIONS" not in value and "FRAMES_PER_POD" not in value:
            self.err(where, "env needs JOB_COMPLETIONS (= spec.completions) or FRAMES_PER_POD")
        index = env.get("JOB_COMPLETION_INDEX")
        if index and "batch.kubernetes.io/job-completion-index" not in json.dumps(index):
            self.err(where, "env JOB_COMPLETION_INDEX must come from the job-completion-index annotation")
        if "SURFACER_ARGS" in value:
            self.cli_flags(where + " env SURFACER_ARGS", shlex.split(value["SURFACER_ARGS"]), "run particles")
        res = (c.get("resources") or {}).get("requests") or {}
        for r in ("cpu", "memory"):
            if r not in res:
                self.err(where, f"resources.requests.{r} is missing")
        self.security(where, pod, c)
        volumes = {v.get("name"): v for v in pod.get("volumes") or []}
        if value.get("OUT_DIR"):
            self.file_flag(where, "OUT_DIR", value["OUT_DIR"], c, volumes, writable=True)
        if value.get("INPUT_PATTERN"):
            self.file_flag(where, "INPUT_PATTERN", value["INPUT_PATTERN"], c, volumes, writable=False)

    def kustomization_dirs(self) -> dict[str, Doc]:
        return {str(Path(k.path).parent): k for k in self.of_kind("Kustomization")}

    def kustomization(self) -> None:
        kdirs = self.kustomization_dirs()
        paths = {d.path for d in self.m.docs}
        for kdir, k in kdirs.items():
            listed = [str(r) for r in k.body.get("resources") or []]
            base = Path(kdir)
            for r in listed:
                target = os.path.normpath(base / r)
                if (base / r).suffix in (".yaml", ".yml"):
                    if target not in paths:
                        self.err(k.where, f"resource {r} is not a manifest under deploy/{base}")
                elif target not in kdirs:
                    self.err(k.where, f"resource {r} is neither a manifest nor a directory with a kustomization.yaml")
            for f in self.m.yaml_files:
                if str(Path(f).parent) != kdir:
                    continue
                name = Path(f).name
                if name not in listed and name != "kustomization.yaml" and ".example." not in name:
                    self.err(k.where, f"{name} is not listed in resources")
                if ".example." in name and name in listed:
                    self.err(k.where, f"{name} holds placeholders and must not be applied")
            for image in k.body.get("images") or []:
                if image.get("name") != IMAGE_REPO:
                    self.err(k.where, f"images[].name {image.get('name')!r} is not the manifests' image "
                                      f"{IMAGE_REPO!r}")

    def renders(self) -> dict[str, list[Doc]]:
        """The objects each top-level kustomization builds (those no other kustomization lists as a resource)."""
        kdirs = self.kustomization_dirs()
        used = {os.path.normpath(Path(kdir) / str(r))
                for kdir, k in kdirs.items() for r in k.body.get("resources") or []}
        return {kdir: self.render(kdir, kdirs, [kdir]) for kdir in sorted(kdirs) if kdir not in used}

    def render(self, kdir: str, kdirs: dict[str, Doc], stack: list[str]) -> list[Doc]:
        k = kdirs[kdir]
        objects: list[Doc] = []
        for r in k.body.get("resources") or []:
            target = os.path.normpath(Path(kdir) / str(r))
            if target in kdirs:
                if target in stack or any(s.startswith(target + "/") for s in stack):
                    self.err(k.where, f"resource {r}: {target} contains or is this kustomization (kustomize "
                                      "rejects the cycle)")
                    continue
                objects += self.render(target, kdirs, stack + [target])
            else:
                objects += [Doc(f"{d.path} (kustomize {stack[0]})", d.index, copy.deepcopy(d.body))
                            for d in self.m.docs if d.path == target]
        for i, entry in enumerate(k.body.get("patches") or []):
            where = f"{k.where}: patches[{i}]"
            try:
                if "patch" in entry:
                    patch = yaml.safe_load(entry["patch"])
                else:
                    patch = next((d.body for d in self.m.docs if d.path == os.path.normpath(
                        Path(kdir) / str(entry.get("path")))), None)
            except yaml.YAMLError as e:
                self.err(where, f"not valid YAML: {e}")
                continue
            if not isinstance(patch, dict):
                self.err(where, "check_deploy evaluates strategic-merge patches (one object) only")
                continue
            kind, name = patch.get("kind"), (patch.get("metadata") or {}).get("name")
            hits = [d for d in objects if d.body.get("kind") == kind
                    and (d.body.get("metadata") or {}).get("name") == name]
            if not hits:
                self.err(where, f"patches {kind} {name}, which the kustomization does not build")
            for d in hits:
                if patch.get("$patch") == "delete":
                    objects.remove(d)
                else:
                    merge_patch(d.body, {key: v for key, v in patch.items() if key != "$patch"})
        return objects

    def images(self) -> None:
        version = project_version(self.m.cmake)
        found = []
        for d in self.m.docs:
            for c in pod_spec(d).get("containers") or []:
                found.append((f"{d.where} container {c.get('name')}", c.get("image", "")))
        for name, svc in ((self.m.compose or {}).get("services") or {}).items():
            found.append((f"{self.m.compose_path}: service {name}", (svc or {}).get("image", "")))
        for where, image in found:
            repo, tag = image_repo(str(image))
            if repo != IMAGE_REPO:
                self.err(where, f"image {image!r} is not {IMAGE_REPO}:TAG (scripts/build_image.sh builds "
                                f"{IMAGE_REPO}:<version>)")
            elif version and tag != version:
                self.err(where, f"image tag {tag!r} differs from the project version {version} (CMakeLists.txt), "
                                "which scripts/build_image.sh tags by default")

    def compose(self) -> None:
        c = self.m.compose
        if c is None:
            self.errors.append("deploy/: no compose file (a YAML file with services:)")
            return
        where0 = self.m.compose_path
        servers = {}
        for name, svc in (c.get("services") or {}).items():
            svc = svc or {}
            entry, command = svc.get("entrypoint") or [], svc.get("command") or []
            if isinstance(entry, str):
                entry = shlex.split(entry)
            if isinstance(command, str):
                command = shlex.split(command)
            words = [str(x) for x in entry]
            if words[:2] == ["/bin/sh", "-c"] or words[:2] == ["sh", "-c"]:
                words = shlex.split(words[2].replace("$$", "$")) if len(words) > 2 else []
            if "surfacer-server" in words:
                tail = words[words.index("surfacer-server") + 1:]
                servers[name] = (svc, [w for w in tail if w not in ('$@', '"$@"')] + [str(x) for x in command])
            elif not entry and str(command[:1]) != "[]":
                servers[name] = (svc, [str(x) for x in command])
        if len(servers) < 2:
            self.err(where0, f"{len(servers)} surfacer-server service(s); several replicas are the point")
            return
        top_volumes, top_secrets = set(c.get("volumes") or {}), c.get("secrets") or {}
        shared, data_dirs, host_ports = None, {}, {}
        for name, (svc, argv) in servers.items():
            where = f"{where0}: service {name}"
            args = parse_args(argv)
            self.server_flags(where, args)
            self.listen_rules(where, args)
            named = {str(v).split(":")[0] for v in svc.get("volumes") or [] if not str(v).startswith((".", "/"))}
            named &= top_volumes
            if not named:
                self.err(where, "mounts no named volume from the top-level volumes:")
            shared = named if shared is None else shared & named
            data = (args.get("--data-dir") or "").replace("${HOSTNAME}", "$HOSTNAME")
            data_dirs[name] = data.replace("$HOSTNAME", str(svc.get("hostname", f"<container id of {name}>")))
            drain = float(args.get("--drain-seconds") or 30)
            grace = seconds(svc.get("stop_grace_period", "10s"))
            if grace is None or not grace > drain:
                self.err(where, f"stop_grace_period ({svc.get('stop_grace_period', '10s')}) must exceed "
                                f"--drain-seconds ({drain:g})")
            ports = []
            for p in svc.get("ports") or []:
                parts = str(p).split(":")
                if len(parts) >= 2 and parts[-1].isdigit():
                    ports.append(int(parts[-1]))
                    host_ports.setdefault(":".join(parts[:-1]), []).append(name)
            for flag in ("--listen", "--metrics-listen"):
                hp = host_port(args.get(flag))
                if hp and hp[1] not in ports:
                    self.err(where, f"{flag} port {hp[1]} is not published in ports: {svc.get('ports')}")
                if flag == "--metrics-listen" and hp is None:
                    self.err(where, "no --metrics-listen")
            test = [str(t) for t in (svc.get("healthcheck") or {}).get("test") or []]
            if not (test and "surfacer" in test and "health" in test):
                self.err(where, "healthcheck must run `surfacer --server localhost:PORT health` (the CLI in the image)")
            else:
                cli = test[test.index("surfacer") + 1:]
                self.cli_flags(where + " healthcheck", [a for a in cli if a != "health"], "health")
                target = parse_args(cli).get("--server") or ""
                hp = host_port(target)
                listen = host_port(args.get("--listen"))
                if "--tls-cert" in args and hp and listen and hp[1] == listen[1] and not (
                        "--tls-ca" in cli or "--tls" in cli):
                    self.err(where, "the healthcheck dials the TLS port without --tls-ca (or --tls): the handshake "
                                    "fails and every replica stays unhealthy")
            mounted_secrets = {s if isinstance(s, str) else s.get("source") for s in svc.get("secrets") or []}
            for flag in ("--tls-cert", "--tls-key", "--tls-client-ca", "--tokens-file"):
                path = args.get(flag)
                if path and path.startswith("/run/secrets/"):
                    secret = path.split("/")[3]
                    if secret not in mounted_secrets or secret not in top_secrets:
                        self.err(where, f"{flag} {path}: secret {secret} is not declared (service and top level)")
        if not shared:
            self.err(where0, "the replicas share no named volume")
        seen = {}
        for name, d in data_dirs.items():
            if not d:
                continue
            if d in seen:
                self.err(where0, f"services {seen[d]} and {name} both use --data-dir {d}: SQLite must not be "
                                 "shared between processes (use a per-replica subdirectory such as /data/$HOSTNAME)")
            seen[d] = name
        for host, names in host_ports.items():
            if len(names) > 1:
                self.err(where0, f"services {', '.join(names)} publish the same host port {host}")

    def dockerfile(self) -> None:
        text = self.m.dockerfile
        if text is None:
            self.errors.append("deploy/Dockerfile: missing")
            return
        where = "deploy/Dockerfile"
        lines = []
        for raw in re.sub(r"\\\n", " ", text).splitlines():  # join continuation lines
            raw = raw.strip()
            if raw and not raw.startswith("#"):
                lines.append(raw)
        stages: list[tuple[str, list[str]]] = []
        for line in lines:
            word = line.split()[0].upper()
            if word == "FROM":
                stages.append((line.split()[1], []))
            elif stages:
                stages[-1][1].append(line)
        if len(stages) < 2:
            self.err(where, f"{len(stages)} stage(s); expected a multi-stage build (build on debian:12, runtime slim)")
            return
        if stages[0][0] != "debian:12":
            self.err(where, f"the build stage is FROM {stages[0][0]}, expected debian:12 (the README's platform)")
        if not stages[-1][0].startswith("debian:12"):
            self.err(where, f"the runtime stage is FROM {stages[-1][0]}, expected debian:12-slim")
        build = stages[0][1]
        if not any(l.upper().startswith("RUN") and "scripts/setup.sh" in l for l in build):
            self.err(where, "the build stage does not RUN scripts/setup.sh (the README's setup script)")
        copied = set()
        for l in build:
            if l.upper().startswith("COPY") and "--from" not in l:
                parts = l.split()[1:]
                for src in parts[:-1] if len(parts) > 1 else []:
                    copied.add(src.rstrip("/") or ".")
        if "." not in copied:
            needed = {"CMakeLists.txt", "scripts/setup.sh"}
            needed |= self.cmake_subdirectories(build)
            for n in sorted(needed - copied):
                self.err(where, f"the build stage does not COPY {n}, which the build needs")
        final = stages[-1][1]
        users = [l.split()[1] for l in final if l.upper().startswith("USER")]
        if not users or users[-1].split(":")[0] in ("0", "root"):
            self.err(where, "the runtime stage has no non-root USER")
        elif not users[-1].split(":")[0].isdigit():
            self.err(where, f"USER {users[-1]}: use a numeric uid so runAsNonRoot can verify it")
        exposed = {int(p.split("/")[0]) for l in final if l.upper().startswith("EXPOSE") for p in l.split()[1:]}
        for d in self.of_kind("Deployment") + self.of_kind("StatefulSet"):
            for c in pod_spec(d).get("containers") or []:
                for p in c.get("ports") or []:
                    if p.get("containerPort") not in exposed:
                        self.err(where, f"does not EXPOSE {p.get('containerPort')} ({d.where} uses it)")
        if not any(l.upper().startswith("COPY") and "--from" in l and "surfacer-server" in l for l in final):
            self.err(where, "the runtime stage does not copy surfacer-server from the build stage")
        if not any(l.upper().startswith("COPY") and ENTRY_SCRIPT in l for l in final):
            self.err(where, f"the runtime stage does not copy deploy/{ENTRY_SCRIPT} (the Indexed Job's entry)")
        for l in final:
            if l.upper().startswith("CMD") and "[" in l:
                try:
                    self.server_flags(where + " CMD", parse_args(json.loads(l[3:].strip())))
                except json.JSONDecodeError:
                    self.err(where, f"CMD is not a JSON array: {l}")

    def cmake_subdirectories(self, build_lines: list[str]) -> set[str]:
        """Directories the top CMakeLists.txt adds, minus those behind an option the Dockerfile turns OFF."""
        text = self.m.cmake or ""
        off = set(re.findall(r"-D(\w+)=(?:OFF|0|FALSE|NO)\b", " ".join(build_lines)))
        on = set(re.findall(r"-D(\w+)=(?:ON|1|TRUE|YES)\b", " ".join(build_lines)))
        defaults = {n: v.upper() == "ON" for n, v in re.findall(r"option\(\s*(\w+)\s+\"[^\"]*\"\s+(ON|OFF)", text)}
        needed, stack = set(), []
        for line in text.splitlines():
            line = line.split("#")[0].strip()
            m = re.match(r"if\s*\(\s*(\w+(?:\s+(?:OR|AND)\s+\w+)*)\s*\)", line, re.I)
            if m:
                # Options joined by OR / AND (evaluated left to right, as CMake does without parentheses).
                words = m.group(1).split()
                is_on = lambda n: n in on or (n not in off and defaults.get(n, True))
                enabled = is_on(words[0])
                for op, name in zip(words[1::2], words[2::2]):
                    enabled = (enabled or is_on(name)) if op.upper() == "OR" else (enabled and is_on(name))
                stack.append(enabled)
                continue
            if re.match(r"if\s*\(", line, re.I):
                stack.append(True)  # a condition this check does not evaluate: assume the directory is built
            elif re.match(r"endif\s*\(", line, re.I) and stack:
                stack.pop()
            else:
                m = re.match(r"add_subdirectory\s*\(\s*([\w./-]+)", line)
                if m and all(stack):
                    needed.add(m.group(1).rstrip("/"))
        return needed


# -------------------------------------------------------------------------------------------------------- self-test
def find_doc(model: Model, kind: str, pred=lambda d: True) -> Doc:
    return next(d for d in model.docs if d.body.get("kind") == kind and pred(d))


def server_container(model: Model) -> dict:
    return pod_spec(find_doc(model, "Deployment"))["containers"][0]


def sts_container(model: Model) -> dict:
    return pod_spec(find_doc(model, "StatefulSet"))["containers"][0]


def durable_patch(model: Model, kind: str) -> dict:
    """The kustomization entry that patches a `kind` (the durable overlay's HPA retarget)."""
    k = find_doc(model, "Kustomization", lambda d: any(f"kind: {kind}" in str(p.get("patch"))
                                                       for p in d.body.get("patches") or []))
    return next(p for p in k.body["patches"] if f"kind: {kind}" in str(p.get("patch")))


def compose_first(model: Model) -> dict:
    return next(iter(model.compose["services"].values()))


def set_arg(args: list, flag: str, value: str) -> None:
    for i, a in enumerate(args):
        if str(a).split("=")[0] == flag:
            args[i] = f"{flag}={value}"
            return
    args.append(f"{flag}={value}")


MUTATIONS = [
    ("readiness probe dropped", "no readinessProbe",
     lambda m: server_container(m).pop("readinessProbe")),
    ("liveness probe made httpGet", "livenessProbe is not a native gRPC probe",
     lambda m: server_container(m).update(livenessProbe={"httpGet": {"path": "/healthz", "port": 9464}})),
    ("readiness probe on the TLS port", "cannot speak TLS",
     lambda m: server_container(m)["readinessProbe"].update(grpc={"port": 50051})),
    ("gRPC probe with a named port", "gRPC probes take no named ports",
     lambda m: server_container(m)["livenessProbe"].update(grpc={"port": "grpc-health"})),
    ("PDB selector broken", "PodDisruptionBudget surfacer: selector",
     lambda m: find_doc(m, "PodDisruptionBudget").body["spec"]["selector"]["matchLabels"].update(
         {"app.kubernetes.io/name": "surfacr"})),
    ("headless Service selector broken", "matches no Deployment's pod labels",
     lambda m: find_doc(m, "Service", lambda d: d.body["spec"].get("clusterIP") == "None")
     .body["spec"]["selector"].update({"app.kubernetes.io/component": "sever"})),
    ("headless Service given a cluster IP", "no headless Service",
     lambda m: find_doc(m, "Service", lambda d: d.body["spec"].get("clusterIP") == "None")
     .body["spec"].pop("clusterIP")),
    ("Service targets a port nobody exposes", "which no selected container exposes",
     lambda m: find_doc(m, "Service").body["spec"]["ports"][0].update(targetPort="grcp")),
    ("HPA targets another Deployment", "scaleTargetRef",
     lambda m: find_doc(m, "HorizontalPodAutoscaler").body["spec"]["scaleTargetRef"].update(name="surfacer-old")),
    ("Deployment selector differs from its pod labels", "spec.selector.matchLabels do not match",
     lambda m: find_doc(m, "Deployment").body["spec"]["selector"]["matchLabels"].update(extra="x")),
    ("container port dropped", "is not among the container ports",
     lambda m: server_container(m).update(ports=[p for p in server_container(m)["ports"] if p["name"] != "metrics"])),
    ("CPU request dropped", "resources.requests.cpu is missing",
     lambda m: server_container(m)["resources"]["requests"].pop("cpu")),
    ("grace period shorter than the drain", "must exceed --drain-seconds",
     lambda m: pod_spec(find_doc(m, "Deployment")).update(terminationGracePeriodSeconds=20)),
    ("writable root file system", "readOnlyRootFilesystem is not true",
     lambda m: server_container(m)["securityContext"].update(readOnlyRootFilesystem=False)),
    ("plain text on 0.0.0.0 without --allow-insecure", "is refused by the server",
     lambda m: server_container(m).update(args=[a for a in server_container(m)["args"]
                                                if not str(a).startswith(("--tls-cert", "--tls-key"))])),
    ("tokens file outside every volume", "--tokens-file /etc/elsewhere/tokens is on no volume",
     lambda m: set_arg(server_container(m)["args"], "--tokens-file", "/etc/elsewhere/tokens")),
    ("image name differs", "is not surfacer:TAG",
     lambda m: pod_spec(find_doc(m, "Job"))["containers"][0].update(image="surfacer-server:0.1.0")),
    ("Job not Indexed", "expected Indexed",
     lambda m: find_doc(m, "Job").body["spec"].update(completionMode="NonIndexed")),
    ("JOB_COMPLETIONS differs from completions", "differs from spec.completions",
     lambda m: find_doc(m, "Job").body["spec"].update(completions=5)),
    ("Job pods labelled like the servers", "also matches the Job's pods",
     lambda m: find_doc(m, "Job").body["spec"]["template"]["metadata"].update(labels=dict(pod_labels(
         find_doc(m, "Deployment"))))),
    ("entry script ignores JOB_COMPLETION_INDEX", "does not read JOB_COMPLETION_INDEX",
     lambda m: setattr(m, "entry_script", (m.entry_script or "").replace("JOB_COMPLETION_INDEX", "POD_INDEX"))),
    ("StatefulSet readiness probe dropped", "StatefulSet surfacer container surfacer: no readinessProbe",
     lambda m: sts_container(m).pop("readinessProbe")),
    ("StatefulSet probe on the TLS port", "cannot speak TLS",
     lambda m: sts_container(m)["livenessProbe"].update(grpc={"port": 50051})),
    ("StatefulSet CPU request dropped", "StatefulSet surfacer container surfacer: resources.requests.cpu is missing",
     lambda m: sts_container(m)["resources"]["requests"].pop("cpu")),
    ("StatefulSet metrics port dropped", "StatefulSet surfacer container surfacer: --metrics-listen port 9464",
     lambda m: sts_container(m).update(ports=[p for p in sts_container(m)["ports"] if p["name"] != "metrics"])),
    ("StatefulSet runs as root", "StatefulSet surfacer container surfacer: runs as uid 0",
     lambda m: pod_spec(find_doc(m, "StatefulSet"))["securityContext"].update(runAsUser=0)),
    ("StatefulSet selector differs from its pod labels", "StatefulSet surfacer: spec.selector.matchLabels",
     lambda m: find_doc(m, "StatefulSet").body["spec"]["selector"]["matchLabels"].update(extra="x")),
    ("StatefulSet pod labels no longer match the PDB",
     "(kustomize k8s/durable): PodDisruptionBudget surfacer: selector",
     lambda m: [labels.update({"app.kubernetes.io/component": "store"}) for labels in (
         find_doc(m, "StatefulSet").body["spec"]["selector"]["matchLabels"], pod_labels(find_doc(m, "StatefulSet")))]),
    ("StatefulSet PVC not mounted", "is not on a volumeClaimTemplate",
     lambda m: sts_container(m).update(volumeMounts=[v for v in sts_container(m)["volumeMounts"]
                                                     if v["name"] != "data"] + [{"name": "tmp",
                                                                                 "mountPath": "/var/lib/surfacer"}])),
    ("StatefulSet store back on an emptyDir", "no volumeClaimTemplates",
     lambda m: [find_doc(m, "StatefulSet").body["spec"].pop("volumeClaimTemplates"),
                pod_spec(find_doc(m, "StatefulSet"))["volumes"].append({"name": "data", "emptyDir": {}})]),
    ("StatefulSet claim shared (ReadWriteMany)", "expected [ReadWriteOnce]",
     lambda m: find_doc(m, "StatefulSet").body["spec"]["volumeClaimTemplates"][0]["spec"].update(
         accessModes=["ReadWriteMany"])),
    ("StatefulSet claim smaller than --retain-bytes", "below the data claim's storage request",
     lambda m: find_doc(m, "StatefulSet").body["spec"]["volumeClaimTemplates"][0]["spec"]["resources"]["requests"]
     .update(storage="4Gi")),
    ("StatefulSet OrderedReady", "expected Parallel",
     lambda m: find_doc(m, "StatefulSet").body["spec"].update(podManagementPolicy="OrderedReady")),
    ("StatefulSet serviceName not the headless Service", "serviceName 'surfacer' is not a headless Service",
     lambda m: find_doc(m, "StatefulSet").body["spec"].update(serviceName="surfacer")),
    ("durable HPA left pointing at the Deployment kind",
     "(kustomize k8s/durable): HorizontalPodAutoscaler surfacer: scaleTargetRef apps/v1 Deployment/surfacer",
     lambda m: durable_patch(m, "HorizontalPodAutoscaler").update(
         patch=durable_patch(m, "HorizontalPodAutoscaler")["patch"].replace("kind: StatefulSet", "kind: Deployment"))),
    ("durable overlay drops the HPA patch", "scaleTargetRef apps/v1 Deployment/surfacer names no workload",
     lambda m: find_doc(m, "Kustomization", lambda d: "patches" in d.body).body.pop("patches")),
    ("durable overlay forgets statefulset.yaml", "statefulset.yaml is not listed in resources",
     lambda m: find_doc(m, "Kustomization", lambda d: "patches" in d.body).body["resources"].remove(
         "statefulset.yaml")),
    ("compose replicas share one data dir", "SQLite must not be shared",
     lambda m: [s.update(entrypoint=["surfacer-server", "--data-dir", "/var/lib/surfacer/shared"])
                for s in m.compose["services"].values()]),
    ("compose healthcheck dropped", "healthcheck must run",
     lambda m: compose_first(m).pop("healthcheck")),
    ("compose stop_grace_period shorter than the drain", "stop_grace_period",
     lambda m: compose_first(m).update(stop_grace_period="10s")),
    ("Dockerfile on ubuntu", "expected debian:12",
     lambda m: setattr(m, "dockerfile", m.dockerfile.replace("FROM debian:12 AS build", "FROM ubuntu:24.04 AS build"))),
    ("Dockerfile without scripts/setup.sh", "does not RUN scripts/setup.sh",
     lambda m: setattr(m, "dockerfile", m.dockerfile.replace("RUN scripts/setup.sh", "RUN apt-get update #"))),
    ("Dockerfile single-stage", "expected a multi-stage build",
     lambda m: setattr(m, "dockerfile", re.sub(r"\nFROM debian:12-slim[^\n]*", "\n", m.dockerfile))),
    ("Dockerfile forgets a source directory", "does not COPY core",
     lambda m: setattr(m, "dockerfile", m.dockerfile.replace("COPY core/ core/", ""))),
]


def self_test(model: Model, flags: Flags, baseline: list[str]) -> int:
    mutations = list(MUTATIONS)
    if flags.server is not None:
        mutations.append(("unknown server flag", "--no-such-flag",
                          lambda m: server_container(m)["args"].append("--no-such-flag=1")))
    if flags.cli_global is not None:
        mutations.append(("unknown CLI flag in the Job", "--no-such-option",
                          lambda m: next(e for e in pod_spec(find_doc(m, "Job"))["containers"][0]["env"]
                                         if e["name"] == "SURFACER_ARGS").update(value="--no-such-option 1")))
    failed = 0
    base = set(baseline)
    for name, expected, mutate in mutations:
        broken = copy.deepcopy(model)
        try:
            mutate(broken)
        except (KeyError, StopIteration, IndexError, TypeError, AttributeError) as e:
            print(f"self-test FAIL: {name}: the manifests no longer have what this case breaks ({e!r})")
            failed += 1
            continue
        new = [e for e in Checker(broken, flags).run() if e not in base]
        if any(expected in e for e in new):
            print(f"self-test ok: {name}: {next(e for e in new if expected in e)}")
        else:
            print(f"self-test FAIL: {name}: expected an error containing {expected!r}, got {new or 'none'}")
            failed += 1
    print(f"self-test: {len(mutations) - failed}/{len(mutations)} broken manifests caught")
    return failed


def main(argv: list[str]) -> int:
    run_self_test = "--self-test" in argv
    positional = [a for a in argv if a != "--self-test"]
    if not 1 <= len(positional) <= 3 or any(a.startswith("-") for a in positional):
        print(__doc__, file=sys.stderr)
        return 2
    deploy = Path(positional[0])
    if not deploy.is_dir():
        print(f"check_deploy: {deploy} is not a directory (give the repository's deploy/)", file=sys.stderr)
        return 2
    try:
        flags = load_flags(positional[1] if len(positional) > 1 else None,
                           positional[2] if len(positional) > 2 else None)
    except (OSError, RuntimeError, subprocess.TimeoutExpired) as e:
        print(f"check_deploy: cannot read the flags: {e}", file=sys.stderr)
        return 2
    if flags.server is None:
        print("check_deploy: note: no SERVER_BIN given, server flags are not checked against surfacer-server --help")
    if flags.cli_global is None:
        print("check_deploy: note: no CLI_BIN given, CLI flags are not checked against surfacer --help")
    model, errors = load(deploy)
    errors += Checker(model, flags).run()
    for e in errors:
        print(f"check_deploy: {e}")
    kinds = sorted({d.body.get("kind") for d in model.docs})
    if not errors:
        print(f"check_deploy: OK: {len(model.docs)} Kubernetes objects ({', '.join(kinds)}), "
              f"{len((model.compose or {}).get('services') or {})} compose services, Dockerfile")
    failed = self_test(model, flags, errors) if run_self_test else 0
    return 1 if errors or failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
