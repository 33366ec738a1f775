"""deploy/: the Dockerfile's targets, compose and Kubernetes files parse and hold what the
cluster needs. Docker cannot build or run here (deploy/smoke.sh does, where it can): the compose
files are validated against the Compose Specification's JSON schema (as vendored by
check-jsonschema), and with `docker compose config` where Compose is installed."""

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
    for package in ("libegl1", "libegl-mesa0", "libgl1-mesa-dri"):
        assert re.search(rf"\b{package}\b", cpu), package
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
    docs = [
        d
        for f in sorted((DEPLOY / "k8s").glob("*.yaml"))
        for d in yaml.safe_load_all(f.read_text())
        if d and "metadata" in d
    ]
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
    assert queues == {"forest-worker": ["default"], "forest-gpu-worker": ["gpu", "render"]}


def _pod_specs() -> list[tuple[str, dict[str, Any]]]:
    """(name, pod spec) of every workload in deploy/k8s (Deployments, StatefulSets, Jobs...)."""
    specs = []
    for f in sorted((DEPLOY / "k8s").glob("*.yaml")):
        for d in yaml.safe_load_all(f.read_text()):
            template = (d or {}).get("spec", {}).get("template") if isinstance(d, dict) else None
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
