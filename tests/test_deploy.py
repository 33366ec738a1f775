"""deploy/: the Dockerfile's targets, compose and Kubernetes files parse and hold what the
cluster needs. Docker cannot build or run here (deploy/smoke.sh does, where it can): the compose
files are validated against the Compose Specification's JSON schema (as vendored by
check-jsonschema), and with `docker compose config` where Compose is installed; the kustomize
overlays are built with `kubectl kustomize` where kubectl is installed, and checked as YAML
(resources that exist, names that match) everywhere."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
import yaml

from service.settings import ServiceSettings

DEPLOY = Path(__file__).parents[1] / "deploy"


def test_compose_services_wait_for_healthy_dependencies() -> None:
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"postgres", "rabbitmq", "api", "worker", "gpu-worker"}
    for name, svc in services.items():
        assert "healthcheck" in svc or name in ("worker", "gpu-worker"), name
        for dep in svc.get("depends_on", {}).values():
            assert dep == {"condition": "service_healthy"}
    gpu = services["gpu-worker"]["deploy"]["resources"]["reservations"]["devices"][0]
    assert gpu["driver"] == "nvidia" and "gpu" in gpu["capabilities"]
    for name in ("api", "worker", "gpu-worker"):
        env = services[name]["environment"]
        assert {"FOREST_DATABASE_URL", "FOREST_BROKER_URL", "FOREST_ARTIFACTS_DIR"} <= set(env)
        build = services[name]["build"]
        assert build["dockerfile"] == "deploy/Dockerfile", name
        assert build["target"] in _stages(), name


def _stages() -> dict[str, str]:
    """deploy/Dockerfile's stages: name -> its text (FROM line included), ARGs resolved."""
    text = (DEPLOY / "Dockerfile").read_text()
    args = dict(re.findall(r"^ARG (\w+)=(\S+)$", text, re.M))
    stages: dict[str, str] = {}
    for part in re.split(r"^(?=FROM )", text, flags=re.M)[1:]:
        head = re.match(r"FROM (\S+) AS ([\w-]+)", part)
        assert head, part.splitlines()[0]
        base = re.sub(r"\$\{(\w+)\}", lambda m: args[m.group(1)], head.group(1))
        stages[head.group(2)] = part.replace(head.group(1), base, 1)
    return stages


def test_one_dockerfile_with_a_target_per_image() -> None:
    """deploy/Dockerfile replaces the three Dockerfiles: core (API runtime), api, worker-cpu
    (Mesa's EGL, the renderer), worker-gpu (an NVIDIA CUDA runtime with libglvnd's EGL)."""
    assert sorted(p.name for p in DEPLOY.glob("*Dockerfile*")) == ["Dockerfile"]
    stages = _stages()
    assert {"core", "api", "worker-cpu", "worker-gpu"} <= set(stages)
    assert stages["api"].startswith("FROM core ") and "service.server" in stages["api"]
    cpu, gpu = stages["worker-cpu"], stages["worker-gpu"]
    assert cpu.startswith("FROM core ")
    # libgl1: the GL dispatch library glcontext opens (libGL.so.1) beside Mesa's EGL
    for package in ("libegl1", "libegl-mesa0", "libgl1", "libgl1-mesa-dri"):
        assert re.search(rf"(?<![\w-]){re.escape(package)}(?![\w-])", cpu), package
    # meshoptimizer has no Linux wheel: built where g++ is, the runtimes install the wheels
    assert "g++" in stages["wheel"] and "pip wheel --wheel-dir /wheels ." in stages["wheel"]
    assert "g++" not in stages["core"] + cpu + gpu
    assert "--find-links /wheels" in stages["core"] and "--find-links /wheels" in cpu
    # no frontend image to pull (an air-gapped builder has BuildKit's built-in one)
    assert not (DEPLOY / "Dockerfile").read_text().startswith("# syntax=")
    ignored = (DEPLOY.parent / ".dockerignore").read_text().split()
    assert {".git", ".venv*", "tests", "docs"} <= set(ignored)  # a small build context
    assert "[service,render]" in cpu  # moderngl: the CPU worker renders too
    assert gpu.startswith("FROM nvidia/cuda:") and "-runtime-" in gpu.splitlines()[0]
    assert "libEGL_nvidia.so.0" in gpu and "graphics" in gpu and "[worker]" in gpu
    for name in ("worker-cpu", "worker-gpu"):  # Docker's health check: the registry probe
        assert 'CMD ["python", "-m", "worker.probe"]' in stages[name], name
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())["services"]
    for service, target in (("worker", "worker-cpu"), ("gpu-worker", "worker-gpu")):
        cmd = re.findall(r"^CMD (\[.*\])$", stages[target], re.M)[-1]
        assert json.loads(cmd) == compose[service]["command"], target


def test_smoke_script_needs_only_docker() -> None:
    script = DEPLOY / "smoke.sh"
    text = script.read_text()
    assert os.access(script, os.X_OK) and text.startswith("#!/usr/bin/env bash\n")
    assert "set -euo pipefail" in text
    for target in ("api", "worker-cpu", "worker-gpu"):
        assert f"build {target}" in text, target
    assert "worker.probe" in text and "llvmpipe" in text
    # Docker alone: no host HTTP client, Compose or kubectl (Python runs in the images)
    code = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    assert not re.search(r"\b(curl|wget|kubectl|docker-compose|docker compose)\b", code)
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    if shutil.which("shellcheck"):
        done = subprocess.run(["shellcheck", str(script)], capture_output=True, text=True)
        assert done.returncode == 0, done.stdout


def _consumed(services: dict[str, Any], profile: str | None) -> set[str]:
    """The queues the workers `docker compose [--profile P] up` starts consume."""
    queues: set[str] = set()
    for svc in services.values():
        command = svc.get("command") or []
        if "worker" in command and set(svc.get("profiles", [])) <= {profile}:
            queues |= set(command[command.index("-Q") + 1].split(","))
    return queues


def test_compose_renders_without_a_gpu_and_with_one() -> None:
    """Plain `docker compose up` (no GPU on the host) consumes every queue a job without a
    pool goes to, renders included (CPU workers, llvmpipe); the GPU worker comes only with
    the `gpu` profile and takes the `gpu` pool's renders and any pool's."""
    from farm.dispatch import KIND_QUEUES, QUEUES

    services = yaml.safe_load((DEPLOY / "compose.yaml").read_text())["services"]
    assert services["gpu-worker"]["profiles"] == ["gpu"]
    assert set(KIND_QUEUES.values()) | {"cpu"} <= _consumed(services, None)
    assert _consumed(services, "gpu") == set(QUEUES)
    assert services["worker"]["build"]["target"] == "worker-cpu"
    assert "libegl-mesa0" in _stages()["worker-cpu"]


class _ComposeLoader(yaml.SafeLoader):
    """YAML with Compose's merge tags: ``!override`` marks a value that replaces, not merges."""


class _Override(dict):  # type: ignore[type-arg]
    pass


_ComposeLoader.add_constructor(
    "!override", lambda loader, node: _Override(loader.construct_mapping(node, deep=True))
)


def _merge(base: object, over: object) -> object:
    """Compose's merge rules for the mappings these files use: keys merge recursively unless
    the override says ``!override``."""
    if isinstance(over, _Override) or not (isinstance(base, dict) and isinstance(over, dict)):
        return dict(over) if isinstance(over, _Override) else over
    return {k: _merge(base[k], v) if k in base else v for k, v in over.items()} | {
        k: v for k, v in base.items() if k not in over
    }


def test_compose_redis_variant_replaces_rabbitmq() -> None:
    base = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    over = yaml.load((DEPLOY / "compose.redis.yaml").read_text(), _ComposeLoader)
    merged = _merge(base, over)
    assert isinstance(merged, dict)
    services = merged["services"]
    assert services["rabbitmq"]["profiles"] == ["rabbitmq"]  # not started by default
    assert "healthcheck" in services["redis"]
    for name in ("api", "worker", "gpu-worker"):
        svc = services[name]
        assert "rabbitmq" not in svc["depends_on"] and "redis" in svc["depends_on"], name
        for dep in svc["depends_on"].values():
            assert dep == {"condition": "service_healthy"}
        env = {k: str(v) for k, v in svc["environment"].items()}
        settings = ServiceSettings(**{k.removeprefix("FOREST_").lower(): v for k, v in env.items()})
        assert settings.is_redis, name
        assert settings.database_url == env["FOREST_DATABASE_URL"]  # the base's, kept
    assert "redis" in merged["volumes"]


COMPOSE_ENV = {"POSTGRES_PASSWORD": "p", "RABBITMQ_PASSWORD": "r", "FOREST_API_KEYS": "k=t"}


def _compose_schema() -> dict[str, Any]:
    """The Compose Specification's JSON schema, as check-jsonschema vendors it (its
    `check-compose-spec` hook)."""
    vendor = resources.files("check_jsonschema.builtin_schemas.vendor")
    schema: dict[str, Any] = json.loads((vendor / "compose-spec.json").read_text())
    return schema


def test_compose_files_match_the_compose_spec() -> None:
    """Each compose file, and the Redis variant merged over the base, validates against the
    Compose Specification's schema; a wrong key or type is caught (the check bites)."""
    import jsonschema

    schema = _compose_schema()
    validator = jsonschema.validators.validator_for(schema)(schema)
    base = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    over = yaml.load((DEPLOY / "compose.redis.yaml").read_text(), _ComposeLoader)
    for what, doc in (("compose.yaml", base), ("compose.redis.yaml", over)):
        errors = [f"{list(e.absolute_path)}: {e.message}" for e in validator.iter_errors(doc)]
        assert errors == [], what
    merged = _merge(base, over)
    assert list(validator.iter_errors(merged)) == []
    broken = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    broken["services"]["worker"]["deploy"]["replica"] = 2  # a typo of replicas
    broken["services"]["api"]["build"]["target"] = ["api"]  # a list, not a string
    errors = list(validator.iter_errors(broken))
    assert {tuple(e.absolute_path)[:2] for e in errors} == {
        ("services", "worker"),
        ("services", "api"),
    }
    assert any("'replica'" in e.message for e in errors)


@pytest.mark.skipif(
    shutil.which("docker") is None
    or subprocess.run(["docker", "compose", "version"], capture_output=True).returncode != 0,
    reason="Docker Compose is not installed here: the schema check above stands for it",
)
def test_docker_compose_config() -> None:
    env = {**os.environ, **COMPOSE_ENV}
    for files in (["compose.yaml"], ["compose.yaml", "compose.redis.yaml"]):
        args = [a for f in files for a in ("-f", str(DEPLOY / f))]
        done = subprocess.run(
            ["docker", "compose", *args, "config", "-q"], env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr


def test_kubernetes_manifests() -> None:
    docs = [d for _, d in _k8s_docs()]
    kinds = {(d["kind"], d["metadata"]["name"]) for d in docs}
    assert {
        ("Deployment", "forest-api"),
        ("Service", "forest-api"),
        ("Deployment", "forest-worker"),
        ("Deployment", "forest-gpu-worker"),
        ("ScaledObject", "forest-worker"),
        ("ScaledObject", "forest-gpu-worker"),
    } <= kinds
    gpu = next(
        d
        for d in docs
        if d["metadata"].get("name") == "forest-gpu-worker" and d["kind"] == "Deployment"
    )
    limits = gpu["spec"]["template"]["spec"]["containers"][0]["resources"]["limits"]
    assert limits["nvidia.com/gpu"] == 1
    scaled = [d for d in docs if d["kind"] == "ScaledObject"]
    queues = {
        d["metadata"]["name"]: [t["metadata"]["queueName"] for t in d["spec"]["triggers"]]
        for d in scaled
    }
    # each Deployment scales on every queue it consumes (a CPU-pool backlog adds CPU workers)
    consumed = {}
    for d in docs:
        if d["kind"] == "Deployment" and d["metadata"]["name"] in queues:
            args = d["spec"]["template"]["spec"]["containers"][0]["args"]
            consumed[d["metadata"]["name"]] = sorted(args[args.index("-Q") + 1].split(","))
    assert {name: sorted(q) for name, q in queues.items()} == consumed


def _pod_specs() -> list[tuple[str, dict[str, Any]]]:
    """(name, pod spec) of every workload in deploy/k8s (Deployments, StatefulSets, Jobs...)."""
    specs = []
    for _, d in _k8s_docs():
        template = d.get("spec", {}).get("template")
        if template is not None:
            specs.append((d["metadata"]["name"], template["spec"]))
    return specs


def test_kubernetes_pods_are_locked_down() -> None:
    specs = _pod_specs()
    assert {name for name, _ in specs} >= {"forest-api", "forest-worker", "forest-gpu-worker"}
    for name, spec in specs:
        pod = spec.get("securityContext", {})
        assert pod.get("runAsNonRoot") is True and pod.get("runAsUser", 0) > 0, name
        assert pod.get("seccompProfile") == {"type": "RuntimeDefault"}, name
        mounts = {v["name"] for v in spec.get("volumes", [])}
        for c in spec["containers"] + spec.get("initContainers", []):
            sc = c.get("securityContext", {})
            where = f"{name}/{c['name']}"
            assert sc.get("allowPrivilegeEscalation") is False, where
            assert sc.get("readOnlyRootFilesystem") is True, where
            assert sc.get("capabilities", {}).get("drop") == ["ALL"], where
            assert not sc.get("capabilities", {}).get("add"), where
            assert not sc.get("privileged"), where
            # a read-only root needs a writable /tmp (tempfile, multiprocessing)
            tmp = [m for m in c.get("volumeMounts", []) if m["mountPath"] == "/tmp"]
            assert tmp and tmp[0]["name"] in mounts, where


def _defaulted_secrets(text: str) -> list[str]:
    """Secrets in a compose file that Compose would start without: a password, key or
    credential URL not written as ``${VAR:?message}``."""
    found = []
    for var, rest in re.findall(r"\$\{(\w+)([^}]*)\}", text):
        if re.search(r"PASSWORD|PASS$|SECRET|KEYS?$", var) and not rest.startswith(":?"):
            found.append(var)
    compose = yaml.load(text, _ComposeLoader)
    for name, svc in compose.get("services", {}).items():
        env = svc.get("environment") or {}
        for key, value in env.items() if isinstance(env, dict) else ():
            secrets = re.findall(r"//\w+:([^@]+)@", str(value))  # a password in a URL
            if re.search(r"PASSWORD|PASS$", key):
                secrets.append(str(value))
            found += [f"{name}.{key}" for v in secrets if not re.fullmatch(r"\$\{\w+:\?[^}]*\}", v)]
    return found


def test_compose_has_no_default_passwords() -> None:
    """Every secret comes from the environment (or .env) and Compose refuses to start without
    it (``${VAR:?message}``): no password has a default such as ``forest``."""
    for f in sorted(DEPLOY.glob("compose*.yaml")):
        assert _defaulted_secrets(f.read_text()) == [], f.name
    base = (DEPLOY / "compose.yaml").read_text()
    for weak in (":-forest}", "}"):  # the check sees a default, and a variable left optional
        mutated = base.replace(":?set POSTGRES_PASSWORD}", weak)
        assert "POSTGRES_PASSWORD" in _defaulted_secrets(mutated)
    assert _defaulted_secrets(base.replace("${RABBITMQ_PASSWORD:?set RABBITMQ_PASSWORD}", "forest"))


K8S = DEPLOY / "k8s"
OVERLAYS = ("local", "cluster", "cluster-keda")


def _k8s_docs() -> list[tuple[Path, dict[str, Any]]]:
    """(file, object) of every Kubernetes object under deploy/k8s, the Secret template
    included; kustomizations left out."""
    return [
        (f, d)
        for f in sorted(K8S.rglob("*.yaml"))
        if f.name != "kustomization.yaml"
        for d in yaml.safe_load_all(f.read_text())
        if isinstance(d, dict) and "metadata" in d
    ]


def _kustomization(folder: Path) -> dict[str, Any]:
    k: dict[str, Any] = yaml.safe_load((folder / "kustomization.yaml").read_text())
    return k


def _files_of(folder: Path) -> list[Path]:
    """The object files a kustomization pulls in: its resources and components, recursively."""
    k = _kustomization(folder)
    files: list[Path] = []
    for ref in k.get("resources", []) + k.get("components", []):
        target = (folder / ref).resolve()
        assert target.exists(), f"{folder}: {ref} does not exist"
        files += _files_of(target) if target.is_dir() else [target]
    return files


def _objects_of(folder: Path) -> list[dict[str, Any]]:
    return [d for f in _files_of(folder) for d in yaml.safe_load_all(f.read_text()) if d]


def test_every_deployment_has_liveness_and_readiness() -> None:
    """Every Deployment's containers have both probes; a worker's are its registry row's age
    (``python -m worker.probe``), with a startup probe covering its slow start."""
    deployments = [d for _, d in _k8s_docs() if d["kind"] == "Deployment"]
    assert {d["metadata"]["name"] for d in deployments} >= {
        "forest-api",
        "forest-worker",
        "forest-gpu-worker",
    }
    for d in deployments:
        for c in d["spec"]["template"]["spec"]["containers"]:
            where = f"{d['metadata']['name']}/{c['name']}"
            assert "livenessProbe" in c and "readinessProbe" in c, where
            if "worker" in c.get("args", []):
                for probe in ("startupProbe", "livenessProbe", "readinessProbe"):
                    assert c[probe]["exec"]["command"] == ["python", "-m", "worker.probe"], where
                    assert c[probe]["timeoutSeconds"] >= 5, where
                # the start (imports, migrations) gets minutes; liveness fails after minutes
                start = c["startupProbe"]
                assert start["periodSeconds"] * start["failureThreshold"] >= 180, where
                live = c["livenessProbe"]
                assert live["periodSeconds"] * live.get("failureThreshold", 3) >= 60, where


def test_worker_probe_timing_matches_the_settings() -> None:
    """The ConfigMap's registry timing is what farm/settings.py accepts (the timeout exceeds the
    heartbeat), so the probe's FOREST_WORKER_TIMEOUT_S comes from the same place."""
    from farm.settings import FarmSettings

    config = next(d for _, d in _k8s_docs() if d["kind"] == "ConfigMap")["data"]
    settings = FarmSettings(
        worker_heartbeat_s=config["FOREST_WORKER_HEARTBEAT_S"],
        worker_timeout_s=config["FOREST_WORKER_TIMEOUT_S"],
    )
    assert settings.worker_timeout_s >= 3 * settings.worker_heartbeat_s


def test_secret_is_a_template_not_a_resource() -> None:
    """No kustomization applies a Secret: secret.example.yaml is a template (docs:
    `kubectl create secret`), named as every pod's envFrom expects."""
    secrets = [(f, d) for f, d in _k8s_docs() if d["kind"] == "Secret"]
    assert [f.name for f, _ in secrets] == ["secret.example.yaml"]
    name = secrets[0][1]["metadata"]["name"]
    for folder in [K8S / "base", K8S / "components" / "keda"] + [
        K8S / "overlays" / o for o in OVERLAYS
    ]:
        files = _files_of(folder)
        assert K8S / "secret.example.yaml" not in files, folder
        assert all(d["kind"] != "Secret" for d in _objects_of(folder)), folder
    for _, spec in _pod_specs():
        for c in spec["containers"]:
            refs = [e["secretRef"]["name"] for e in c.get("envFrom", []) if "secretRef" in e]
            assert refs == [name], c["name"]
    assert "kubectl create secret" in (DEPLOY.parent / "docs" / "deploy.md").read_text()


def test_kustomize_overlays() -> None:
    """base has no volume and no KEDA; each overlay adds the artifact claim every pod mounts
    (ReadWriteOnce on one node, ReadWriteMany on a cluster); KEDA is a component that only
    cluster-keda uses, replacing the base's HPA on CPU."""
    assert _kustomization(K8S / "components" / "keda")["kind"] == "Component"
    base = _objects_of(K8S / "base")
    assert all(d["kind"] not in ("PersistentVolumeClaim", "ScaledObject") for d in base)
    hpas = {d["metadata"]["name"]: d for d in base if d["kind"] == "HorizontalPodAutoscaler"}
    assert set(hpas) == {"forest-api", "forest-worker"}
    for name, hpa in hpas.items():
        assert hpa["spec"]["scaleTargetRef"] == {
            "apiVersion": "apps/v1",
            "kind": "Deployment",
            "name": name,
        }
        assert [m["resource"]["name"] for m in hpa["spec"]["metrics"]] == ["cpu"]
    modes = {}
    for overlay in OVERLAYS:
        objects = _objects_of(K8S / "overlays" / overlay)
        claims = {d["metadata"]["name"]: d for d in objects if d["kind"] == "PersistentVolumeClaim"}
        deployments = {d["metadata"]["name"] for d in objects if d["kind"] == "Deployment"}
        for d in objects:
            if d["kind"] == "Deployment":
                for v in d["spec"]["template"]["spec"]["volumes"]:
                    if "persistentVolumeClaim" in v:
                        assert v["persistentVolumeClaim"]["claimName"] in claims, overlay
            if d["kind"] == "ScaledObject":
                assert d["spec"]["scaleTargetRef"]["name"] in deployments, overlay
        (claim,) = claims.values()
        modes[overlay] = claim["spec"]["accessModes"]
        keda = K8S / "components" / "keda" / "scaledobjects.yaml"
        assert (keda in _files_of(K8S / "overlays" / overlay)) == (overlay == "cluster-keda")
    assert modes == {
        "local": ["ReadWriteOnce"],
        "cluster": ["ReadWriteMany"],
        "cluster-keda": ["ReadWriteMany"],
    }


def _kustomize(overlay: str) -> list[dict[str, Any]]:
    done = subprocess.run(
        ["kubectl", "kustomize", str(K8S / "overlays" / overlay)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    return [d for d in yaml.safe_load_all(done.stdout) if d]


@pytest.mark.skipif(shutil.which("kubectl") is None, reason="kubectl is not installed here")
@pytest.mark.parametrize("overlay", OVERLAYS)
def test_kubectl_kustomize_builds(overlay: str) -> None:
    """The overlays as kustomize builds them: the patches apply (local: one API replica and
    the smoke-built images; cluster-keda: KEDA's objects and no HPA for the CPU workers)."""
    objects = _kustomize(overlay)
    kinds = {(d["kind"], d["metadata"]["name"]) for d in objects}
    assert {
        ("ConfigMap", "forest-config"),
        ("Deployment", "forest-api"),
        ("Deployment", "forest-worker"),
        ("Deployment", "forest-gpu-worker"),
        ("HorizontalPodAutoscaler", "forest-api"),
        ("PersistentVolumeClaim", "forest-artifacts"),
    } <= kinds
    assert all(kind != "Secret" for kind, _ in kinds)
    keda = {("ScaledObject", "forest-worker"), ("ScaledObject", "forest-gpu-worker")}
    cpu_hpa = ("HorizontalPodAutoscaler", "forest-worker")
    if overlay == "cluster-keda":
        assert keda <= kinds and cpu_hpa not in kinds
    else:
        assert not keda & kinds and cpu_hpa in kinds
    images = {
        c["image"]
        for d in objects
        if d["kind"] == "Deployment"
        for c in d["spec"]["template"]["spec"]["containers"]
    }
    api = next(
        d for d in objects if d["kind"] == "Deployment" and d["metadata"]["name"] == "forest-api"
    )
    if overlay == "local":
        assert images == {"forest-api:smoke", "forest-worker-cpu:smoke", "forest-worker-gpu:smoke"}
        assert api["spec"]["replicas"] == 1
    else:
        assert all(i.startswith("ghcr.io/example/forest-") for i in images)
        assert api["spec"]["replicas"] == 2
